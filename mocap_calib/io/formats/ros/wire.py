"""IMU and pose messages read in bulk from their serialised bytes, without deserialising each.

Every message type the bag reader takes has a fixed layout: a ``std_msgs/Header`` (stamp and a
``frame_id`` string), for some types a ``child_frame_id`` string, then float64 fields only.
Given all the raw messages of a topic, :func:`read_fixed` finds each message's string lengths
and reads the wanted float64 fields of all messages at once with numpy (ROS 1: little-endian,
packed; ROS 2: CDR, little-endian, float64 aligned to 8 bytes after the 4-byte encapsulation
header). :func:`read_tf` walks ``tf2_msgs/TFMessage`` (a sequence of ``TransformStamped``)
with ``struct``.

A type whose definition in the bag differs from the standard one would be misread: each
message's length must be exactly what the layout says (CDR: up to 3 bytes of padding), and
the first, middle and last messages are also deserialised by ``rosbags`` and must give the
same numbers. If anything disagrees, the functions return None and the caller deserialises
every message (slow, always right).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

IntArray = NDArray[np.int64]
Deserialise = Callable[[bytes], Any]


@dataclass(frozen=True)
class Layout:
    """Where a message type's float64 fields sit, counted in float64s after its strings.

    Attributes:
        child: a ``child_frame_id`` string follows the header.
        fields: name -> (first float64, count).
        size: float64s after the strings (the whole rest of the message).
    """

    child: bool
    fields: dict[str, tuple[int, int]]
    size: int


_POSE = {"position": (0, 3), "orientation": (3, 4)}
LAYOUTS: dict[str, Layout] = {
    # orientation 4, covariance 9, angular_velocity 3, covariance 9, linear_acceleration 3, cov 9
    "sensor_msgs/msg/Imu": Layout(False, {"gyro": (13, 3), "accel": (25, 3)}, 37),
    "geometry_msgs/msg/PoseStamped": Layout(False, _POSE, 7),
    "geometry_msgs/msg/PoseWithCovarianceStamped": Layout(False, _POSE, 7 + 36),
    "geometry_msgs/msg/TransformStamped": Layout(True, _POSE, 7),  # translation, rotation
    "nav_msgs/msg/Odometry": Layout(True, _POSE, 7 + 36 + 6 + 36),  # pose, twist + covariances
}


_BLOCK = 1 << 15


def _u32(buf: NDArray[np.uint8], off: IntArray) -> IntArray:
    b = buf[off[:, None] + np.arange(4)].astype(np.int64)
    return b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16) | (b[:, 3] << 24)


def _align(r: IntArray, k: int) -> IntArray:
    return (r + k - 1) // k * k


class _Batch:
    """All raw messages of a topic in one byte array."""

    def __init__(self, raws: Sequence[bytes]) -> None:
        self.n = len(raws)
        self.length = np.fromiter(map(len, raws), dtype=np.int64, count=self.n)
        self.buf = np.frombuffer(b"".join(raws) + bytes(8), dtype=np.uint8)
        self.start = np.concatenate([[0], np.cumsum(self.length)[:-1]]).astype(np.int64)

    def fits(self, r: IntArray, extra: int) -> bool:
        """Every message holds ``extra`` more bytes after relative offset ``r``."""
        return bool(np.all(r + extra <= self.length))

    def u32(self, r: IntArray) -> IntArray:
        return _u32(self.buf, self.start + r)

    def doubles(self, r: IntArray, first: int, count: int) -> NDArray[np.float64]:
        """(n, count) float64s from relative offset ``r + 8 first`` of each message."""
        at = self.start + r + 8 * first
        width = np.arange(8 * count)
        out = np.empty((self.n, 8 * count), np.uint8)
        for i in range(0, self.n, _BLOCK):  # blocks bound the index array's memory
            out[i:i + _BLOCK] = self.buf[at[i:i + _BLOCK, None] + width]
        return out.view("<f8")


def read_fixed(raws: Sequence[bytes], msgtype: str, ros1: bool, deserialise: Deserialise
               ) -> tuple[IntArray, dict[str, NDArray[np.float64]]] | None:
    """Header stamps (ns) and the layout's fields of every message, or None (see the module)."""
    layout = LAYOUTS.get(msgtype)
    if layout is None or not raws:
        return None
    b = _Batch(raws)
    zero = np.zeros(b.n, np.int64)
    if ros1:  # seq, secs, nsecs, frame_id
        if not b.fits(zero, 16):
            return None
        sec, nsec, r = b.u32(zero + 4), b.u32(zero + 8), 16 + b.u32(zero + 12)
    else:  # encapsulation (CDR little-endian: 00 01), sec, nanosec, frame_id (with its NUL)
        if not b.fits(zero, 16) or np.any(b.buf[b.start] != 0) or np.any(b.buf[b.start + 1] != 1):
            return None
        sec = b.u32(zero + 4)
        sec = np.where(sec >= 2**31, sec - 2**32, sec)
        nsec, r = b.u32(zero + 8), 16 + b.u32(zero + 12)
    if layout.child:
        r = r if ros1 else 4 + _align(r - 4, 4)
        if not b.fits(r, 4):
            return None
        r = r + 4 + b.u32(r)
    if not ros1:
        r = 4 + _align(r - 4, 8)
    end = r + 8 * layout.size
    if np.any(end > b.length) or np.any(b.length - end > (0 if ros1 else 3)):
        return None
    stamps = sec * 1_000_000_000 + nsec
    out = {name: b.doubles(r, first, count) for name, (first, count) in layout.fields.items()}
    for i in sorted({0, b.n // 2, b.n - 1}):
        if not _same(deserialise(raws[i]), msgtype, int(stamps[i]),
                     {k: v[i] for k, v in out.items()}):
            return None
    return stamps, out


def fields_of(msg: Any, msgtype: str) -> tuple[int, dict[str, list[float]]]:
    """Header stamp (ns) and the layout's fields of one deserialised message."""
    st = msg.header.stamp
    if msgtype == "sensor_msgs/msg/Imu":
        w, a = msg.angular_velocity, msg.linear_acceleration
        got = {"gyro": [w.x, w.y, w.z], "accel": [a.x, a.y, a.z]}
    else:
        if msgtype.endswith("TransformStamped"):
            p, q = msg.transform.translation, msg.transform.rotation
        else:
            pose = msg.pose if msgtype.endswith("/PoseStamped") else msg.pose.pose
            p, q = pose.position, pose.orientation
        got = {"position": [p.x, p.y, p.z], "orientation": [q.x, q.y, q.z, q.w]}
    return int(st.sec) * 1_000_000_000 + int(st.nanosec), got


def deserialise_fixed(raws: Sequence[bytes], msgtype: str, deserialise: Deserialise
                      ) -> tuple[IntArray, dict[str, NDArray[np.float64]]]:
    """What :func:`read_fixed` returns, one message at a time (for unusual definitions)."""
    stamps, cols = [], []
    for raw in raws:
        stamp, got = fields_of(deserialise(raw), msgtype)
        stamps.append(stamp)
        cols.append(got)
    names = LAYOUTS[msgtype].fields
    return (np.array(stamps, dtype=np.int64),
            {k: np.array([c[k] for c in cols], dtype=float).reshape(-1, n)
             for k, (_, n) in names.items()})


def _same(msg: Any, msgtype: str, stamp: int, got: dict[str, NDArray[np.float64]]) -> bool:
    """The deserialised message holds the stamp and values read from its bytes."""
    want_stamp, want = fields_of(msg, msgtype)
    return want_stamp == stamp and all(np.array_equal(np.asarray(v, dtype=float), got[k])
                                       for k, v in want.items())


@dataclass(frozen=True)
class Transforms:
    """The transforms of a TF topic, one row each.

    Attributes:
        message: (K,) index of the message that held the transform.
        stamp: (K,) header stamp, ns.
        parent, child: (K,) frame names (leading '/' kept as recorded).
        value: (K, 7) translation xyz, rotation xyzw.
    """

    message: IntArray
    stamp: IntArray
    parent: list[str]
    child: list[str]
    value: NDArray[np.float64]


_R1_HEAD = struct.Struct("<III")
_CDR_HEAD = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_SEVEN = struct.Struct("<7d")


def read_tf(raws: Sequence[bytes], ros1: bool, deserialise: Deserialise) -> Transforms | None:
    """Every transform of every ``TFMessage`` in ``raws``, or None (see the module)."""
    rows: list[tuple[int, int, str, str, tuple[float, ...]]] = []
    names: dict[bytes, str] = {}

    def string(buf: memoryview, r: int) -> tuple[str, int]:
        n = _U32.unpack_from(buf, r)[0]
        raw = bytes(buf[r + 4:r + 4 + n])
        if not ros1:
            raw = raw[:-1]  # CDR strings end with a NUL
        name = names.get(raw)
        if name is None:
            name = names[raw] = raw.decode("utf-8", errors="replace")
        return name, r + 4 + n

    try:
        for k, raw in enumerate(raws):
            buf = memoryview(raw)
            if not ros1 and bytes(buf[:2]) != b"\x00\x01":
                return None
            base = 0 if ros1 else 4
            count, r = _U32.unpack_from(buf, base)[0], base + 4
            for _ in range(count):
                if ros1:
                    _, sec, nsec = _R1_HEAD.unpack_from(buf, r)
                    parent, r = string(buf, r + 12)
                    child, r = string(buf, r)
                else:
                    r = base + -(-(r - base) // 4) * 4
                    sec, nsec = _CDR_HEAD.unpack_from(buf, r)
                    parent, r = string(buf, r + 8)
                    r = base + -(-(r - base) // 4) * 4
                    child, r = string(buf, r)
                    r = base + -(-(r - base) // 8) * 8
                rows.append((k, sec * 1_000_000_000 + nsec, parent, child,
                             _SEVEN.unpack_from(buf, r)))
                r += 56
            if len(raw) - r > (0 if ros1 else 3) or r > len(raw):
                return None
    except (struct.error, IndexError):
        return None
    tf = _transforms(rows)
    return tf if _same_tf(tf, raws, deserialise) else None


def deserialise_tf(raws: Sequence[bytes], deserialise: Deserialise) -> Transforms:
    """What :func:`read_tf` returns, one message at a time (for unusual definitions)."""
    rows = []
    for k, raw in enumerate(raws):
        for m in deserialise(raw).transforms:
            t, q = m.transform.translation, m.transform.rotation
            rows.append((k, int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec),
                         m.header.frame_id, m.child_frame_id, (t.x, t.y, t.z, q.x, q.y, q.z, q.w)))
    return _transforms(rows)


def _transforms(rows: list[tuple[int, int, str, str, tuple[float, ...]]]) -> Transforms:
    return Transforms(np.array([x[0] for x in rows], dtype=np.int64),
                      np.array([x[1] for x in rows], dtype=np.int64), [x[2] for x in rows],
                      [x[3] for x in rows],
                      np.array([x[4] for x in rows], dtype=float).reshape(-1, 7))


def _same_tf(tf: Transforms, raws: Sequence[bytes], deserialise: Deserialise) -> bool:
    """The first, middle and last messages deserialised give the rows read from their bytes."""
    for k in sorted({0, len(raws) // 2, len(raws) - 1}) if raws else []:
        msg = deserialise(raws[k])
        rows = np.flatnonzero(tf.message == k)
        if len(rows) != len(msg.transforms):
            return False
        for i, m in zip(rows.tolist(), msg.transforms, strict=True):
            t, q = m.transform.translation, m.transform.rotation
            want = np.array([t.x, t.y, t.z, q.x, q.y, q.z, q.w])
            stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
            if (stamp != tf.stamp[i] or m.header.frame_id != tf.parent[i]
                    or m.child_frame_id != tf.child[i] or not np.array_equal(want, tf.value[i])):
                return False
    return True
