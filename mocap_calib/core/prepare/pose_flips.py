"""A marker set that flips: the mocap's attitude turns by a large angle between two poses and
stays there (a rigid body whose markers the mocap software matched the wrong way round, often
a symmetric layout), then possibly turns back.

A body cannot turn by 90 degrees between two poses a frame apart (at 20 rad/s, faster than any
drone spins, a 100 Hz frame turns 11 degrees), and the pose screen (:mod:`.pose_screen`) only
removes a few wrong frames among right ones: a flipped stretch of seconds passes it, and then
every later step blames something else (no clock offset matches, or the noise levels absorb
it). So the flips are found here and the session is refused naming them; the user crops the
stretch out or repairs the rigid body.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.errors import InputError

Array = NDArray[np.float64]

#: A step turns by at least this much to be a flip (rad) ...
FLIP_ANGLE = float(np.radians(90.0))
#: ... and by more than this rate allows over the step (rad/s): a pose after a long dropout
#: may legitimately have turned far.
MAX_RATE = 20.0


def flips(t: Array, R: Array) -> NDArray[np.int64]:
    """Indices ``k`` where the attitude jumps from pose ``k`` to ``k + 1`` by more than a body
    can turn (:data:`FLIP_ANGLE`, :data:`MAX_RATE`)."""
    if len(t) < 2:
        return np.zeros(0, dtype=np.int64)
    step = np.linalg.norm(so3.log(np.einsum("nji,njk->nik", R[:-1], R[1:])), axis=1)
    limit = np.maximum(FLIP_ANGLE, MAX_RATE * np.diff(t))
    return np.flatnonzero(step > limit)


def refuse_flips(t: Array, R: Array, source: str) -> None:
    """Refuse a pose stream whose attitude flips, naming where (between which two poses:
    seconds of the mocap log) and by how much.

    Raises:
        InputError: the attitude flips at least once.
    """
    at = flips(t, R)
    if not len(at):
        return
    rel = so3.log(np.einsum("nji,njk->nik", R[at], R[at + 1]))
    deg = np.degrees(np.linalg.norm(rel, axis=1))
    when = [f"{t[k]:.2f}-{t[k + 1]:.2f} s ({d:.0f} deg)"
            for k, d in zip(at[:4], deg[:4], strict=True)]
    more = f" and {len(at) - 4} more" if len(at) > 4 else ""
    span = (f"; between the first two it stays turned for {t[at[1] + 1] - t[at[0] + 1]:.2f} s"
            if len(at) > 1 else "; it stays turned to the end")
    raise InputError(
        f"{source}: the mocap attitude flips between two poses at "
        f"{', '.join(when)}{more} of the mocap log{span}: the rigid body's markers were matched "
        "the wrong way round (a flipped marker set), not a motion; crop that stretch out "
        "(--start/--end) or repair the rigid body in the mocap software")
