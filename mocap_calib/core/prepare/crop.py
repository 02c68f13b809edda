"""``--start``/``--end``: the part of a session to use, cut before anything else looks at it."""

from __future__ import annotations

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError

#: Fewest IMU samples a cropped part may keep.
MIN_SAMPLES = 100


def crop_imu(imu: ImuSamples, start: float | None, end: float | None) -> ImuSamples:
    """The IMU samples from ``start`` to ``end`` (s after the log's first sample)."""
    if start is None and end is None:
        return imu
    lo = imu.t[0] + (start or 0.0)
    hi = imu.t[0] + end if end is not None else np.inf
    if not hi > lo:
        raise InputError(f"--end {end:g} must be after --start {start or 0.0:g}")
    kept = imu.select((imu.t >= lo) & (imu.t <= hi))
    if len(kept) < MIN_SAMPLES:
        span = imu.t[-1] - imu.t[0]
        given = " ".join(f"--{k} {v:g}" for k, v in (("start", start), ("end", end))
                         if v is not None)
        left = ("nothing of the session is left" if len(kept) < 2
                else f"only {len(kept)} IMU samples are left")
        raise InputError(f"{imu.source}: {given}: {left} (the IMU log spans 0 to {span:.1f} s "
                         "from its first sample); choose --start/--end within it")
    return kept


def crop_session(imu: ImuSamples, mocap: MocapPoses, start: float | None, end: float | None,
                 time_offset: float | None = None) -> tuple[ImuSamples, MocapPoses]:
    """The IMU samples from ``start`` to ``end`` (s after the IMU log's first sample); the
    mocap is cut to match (with a margin for the clock offset) only when the raw stamps share
    an epoch. From clocks of different epochs it stays whole: the clock search finds the
    matching stretch."""
    if start is None and end is None:
        return imu, mocap
    imu_c = crop_imu(imu, start, end)
    shift = (imu.time_origin_ns - mocap.time_origin_ns) * 1e-9
    tm = mocap.t - shift  # mocap times on the IMU clock (before the fine offset)
    if tm[-1] < imu.t[0] or tm[0] > imu.t[-1]:  # different epochs
        return imu_c, mocap
    lo = imu.t[0] + (start or 0.0)
    hi = imu.t[0] + end if end is not None else np.inf
    margin = 1.0 if time_offset is None else 1.0 + abs(time_offset)
    return imu_c, mocap.select((tm >= lo - margin) & (tm <= hi + margin))
