"""``tf2_msgs/TFMessage`` read in bulk from its serialised bytes (see :mod:`.wire`).

A TF message is a sequence of ``TransformStamped``: header (stamp, ``frame_id``),
``child_frame_id``, translation and rotation. Messages are grouped by how many transforms they
hold, and each group is decoded transform by transform for all its messages at once (a mocap
driver's ``/tf`` has one group: one, or one per rigid body, transform per message). Frame names
are decoded once per distinct name. The same checks as for the other types guard the layout
(exact lengths; the first, middle and last messages deserialised by ``rosbags`` agree), and
:func:`deserialise_tf` is the message-by-message fall-back.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.io.formats.ros.wire import Batch, Deserialise

IntArray = NDArray[np.int64]
#: Fewest bytes a serialised TransformStamped takes (header, two strings, seven float64s).
_MIN_TRANSFORM = 70


@dataclass(frozen=True)
class Transforms:
    """The transforms of a TF topic, one row each, in message order.

    Attributes:
        message: (K,) index of the message that held the transform.
        stamp: (K,) header stamp, ns.
        parent, child: (K,) indices into ``names`` (frame ids as recorded, '/' and all).
        names: the distinct frame ids.
        value: (K, 7) translation xyz, rotation xyzw.
    """

    message: IntArray
    stamp: IntArray
    parent: IntArray
    child: IntArray
    names: list[str]
    value: NDArray[np.float64]


class _Names:
    def __init__(self) -> None:
        self.names: list[str] = []
        self.code: dict[str, int] = {}

    def add(self, name: str) -> int:
        if name not in self.code:
            self.code[name] = len(self.names)
            self.names.append(name)
        return self.code[name]


def _align(r: IntArray, k: int) -> IntArray:
    """CDR alignment, counted from the end of the 4-byte encapsulation header."""
    return 4 + (r - 4 + k - 1) // k * k


def _strings(b: Batch, r: IntArray, cdr: bool, names: _Names
             ) -> tuple[IntArray, IntArray] | None:
    """Name codes of the strings at offsets ``r`` (u32 length, bytes) and the offsets after."""
    if not b.fits(r, 4):
        return None
    n = b.u32(r)
    if np.any(r + 4 + n > b.length) or (cdr and np.any(n == 0)):
        return None
    codes = np.empty(b.n, np.int64)
    for size in np.unique(n).tolist():
        sel = np.flatnonzero(n == size)
        rows = b.buf[(b.start[sel] + r[sel] + 4)[:, None] + np.arange(size)]
        left = np.arange(len(sel))
        while len(left):  # one distinct name at a time: a TF topic holds a few
            head = rows[left[0]]
            same = np.all(rows[left] == head, axis=1)
            raw = head.tobytes()
            if cdr:  # CDR strings end with a NUL
                if not raw.endswith(b"\0"):
                    return None
                raw = raw[:-1]
            codes[sel[left[same]]] = names.add(raw.decode("utf-8", errors="replace"))
            left = left[~same]
    return codes, r + 4 + n


def _transform(b: Batch, r: IntArray, ros1: bool, names: _Names) -> tuple | None:
    """(stamp, parent, child, (n, 7) values, offsets after) of one TransformStamped per
    message at offsets ``r``."""
    if ros1:  # seq, secs, nsecs, frame_id, child_frame_id, 7 float64 (packed)
        if not b.fits(r, 16):
            return None
        sec, nsec = b.u32(r + 4), b.u32(r + 8)
        got = _strings(b, r + 12, False, names)
        if got is None:
            return None
        parent, r = got
        got = _strings(b, r, False, names)
        if got is None:
            return None
        child, r = got
    else:
        r = _align(r, 4)
        if not b.fits(r, 12):
            return None
        sec, nsec = b.u32(r), b.u32(r + 4)
        sec = np.where(sec >= 2**31, sec - 2**32, sec)
        got = _strings(b, r + 8, True, names)
        if got is None:
            return None
        parent, r = got
        got = _strings(b, _align(r, 4), True, names)
        if got is None:
            return None
        child, r = got
        r = _align(r, 8)
    if not b.fits(r, 56):
        return None
    return sec * 1_000_000_000 + nsec, parent, child, b.doubles(r, 0, 7), r + 56


def read_tf(raws: Sequence[bytes], ros1: bool, deserialise: Deserialise) -> Transforms | None:
    """Every transform of every ``TFMessage`` in ``raws``, or None if the layout does not fit
    (then :func:`deserialise_tf`)."""
    b = Batch(raws)
    names = _Names()
    if b.n == 0:
        return _assemble([], names)
    base = 0 if ros1 else 4
    zero = np.zeros(b.n, np.int64)
    if not b.fits(zero, base + 4) or (not ros1 and not b.cdr_le()):
        return None
    count = b.u32(zero + base)
    if np.any(count * _MIN_TRANSFORM > b.length):
        return None
    parts: list[tuple] = []
    for c in np.unique(count).tolist():
        idx = np.flatnonzero(count == c)
        sub = b.take(idx)
        r = np.full(len(idx), base + 4, np.int64)
        for j in range(c):
            got = _transform(sub, r, ros1, names)
            if got is None:
                return None
            stamp, parent, child, value, r = got
            parts.append((idx, np.full(len(idx), j), stamp, parent, child, value))
        pad = sub.length - r
        if np.any(pad < 0) or np.any(pad > (0 if ros1 else 3)):
            return None
    tf = _assemble(parts, names)
    return tf if _same_tf(tf, raws, deserialise) else None


def _assemble(parts: list[tuple], names: _Names) -> Transforms:
    if not parts:
        empty = np.zeros(0, np.int64)
        return Transforms(empty, empty, empty, empty, names.names, np.zeros((0, 7)))
    cat = [np.concatenate([p[k] for p in parts]) for k in range(6)]
    order = np.lexsort((cat[1], cat[0]))
    return Transforms(cat[0][order], cat[2][order], cat[3][order], cat[4][order], names.names,
                      cat[5][order])


def deserialise_tf(raws: Sequence[bytes], deserialise: Deserialise) -> Transforms:
    """What :func:`read_tf` returns, one message at a time (for unusual definitions)."""
    names = _Names()
    rows = []
    for k, raw in enumerate(raws):
        for j, m in enumerate(deserialise(raw).transforms):
            t, q = m.transform.translation, m.transform.rotation
            rows.append((k, j, int(m.header.stamp.sec) * 1_000_000_000
                         + int(m.header.stamp.nanosec), names.add(m.header.frame_id),
                         names.add(m.child_frame_id), (t.x, t.y, t.z, q.x, q.y, q.z, q.w)))
    if not rows:
        return _assemble([], names)
    cols = list(zip(*rows, strict=True))
    part = (*(np.array(c, dtype=np.int64) for c in cols[:5]),
            np.array(cols[5], dtype=float).reshape(-1, 7))
    return _assemble([part], names)


def _same_tf(tf: Transforms, raws: Sequence[bytes], deserialise: Deserialise) -> bool:
    """The first, middle and last messages deserialised give the rows read from their bytes."""
    for k in sorted({0, len(raws) // 2, len(raws) - 1}):
        msg = deserialise(raws[k])
        rows = np.flatnonzero(tf.message == k)
        if len(rows) != len(msg.transforms):
            return False
        for i, m in zip(rows.tolist(), msg.transforms, strict=True):
            t, q = m.transform.translation, m.transform.rotation
            want = np.array([t.x, t.y, t.z, q.x, q.y, q.z, q.w])
            stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
            if (stamp != tf.stamp[i] or m.header.frame_id != tf.names[tf.parent[i]]
                    or m.child_frame_id != tf.names[tf.child[i]]
                    or not np.array_equal(want, tf.value[i])):
                return False
    return True
