"""IMU and pose messages read in bulk from their serialised bytes, without deserialising each.

Every message type the bag reader takes has a fixed layout: a ``std_msgs/Header`` (stamp and a
``frame_id`` string), for some types a ``child_frame_id`` string, then float64 fields only.
Given all the raw messages of a topic, :func:`read_fixed` finds each message's string lengths
and reads the wanted float64 fields of all messages at once with numpy (ROS 1: little-endian,
packed; ROS 2: CDR, little-endian, float64 aligned to 8 bytes after the 4-byte encapsulation
header). ``tf2_msgs/TFMessage`` is decoded likewise in :mod:`.tf_wire`.

A type whose definition in the bag differs from the standard one would be misread: each
message's length must be exactly what the layout says (CDR: up to 3 bytes of padding), and
the first, middle and last messages are also deserialised by ``rosbags`` and must give the
same numbers. If anything disagrees, the functions return None and the caller deserialises
every message (slow, always right).
"""

from __future__ import annotations

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


class Batch:
    """Raw messages of a topic in one byte array: message ``i`` is
    ``buf[start[i]:start[i] + length[i]]``; offsets ``r`` below are relative to each start."""

    def __init__(self, raws: Sequence[bytes]) -> None:
        self.n = len(raws)
        self.length = np.fromiter(map(len, raws), dtype=np.int64, count=self.n)
        self.buf = np.frombuffer(b"".join(raws) + bytes(8), dtype=np.uint8)
        self.start = np.concatenate([[0], np.cumsum(self.length)[:-1]]).astype(np.int64)

    def take(self, idx: IntArray) -> Batch:
        """The messages ``idx`` (sharing the bytes)."""
        sub = object.__new__(Batch)
        sub.n, sub.buf = len(idx), self.buf
        sub.length, sub.start = self.length[idx], self.start[idx]
        return sub

    def cdr_le(self) -> bool:
        """Every message starts with the CDR little-endian encapsulation header (00 01)."""
        return bool(np.all(self.buf[self.start] == 0) and np.all(self.buf[self.start + 1] == 1))

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
    b = Batch(raws)
    zero = np.zeros(b.n, np.int64)
    if ros1:  # seq, secs, nsecs, frame_id
        if not b.fits(zero, 16):
            return None
        sec, nsec, r = b.u32(zero + 4), b.u32(zero + 8), 16 + b.u32(zero + 12)
    else:  # encapsulation (CDR little-endian: 00 01), sec, nanosec, frame_id (with its NUL)
        if not b.fits(zero, 16) or not b.cdr_le():
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
