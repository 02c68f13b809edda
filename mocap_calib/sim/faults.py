"""IMU logging faults of simulated sessions: the gaps flight controllers' logs have (dropped
samples after logger buffer overruns, stalls)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import InputError

Array = NDArray[np.float64]


def imu_gaps(rng: np.random.Generator, duration: float, t: Array,
             effects: dict[str, list[float] | None], defaults: dict[str, float]
             ) -> tuple[NDArray[np.bool_], list[list[float]]]:
    """IMU samples (times ``t``) kept after the logging faults in ``effects``
    (``imu_dropouts``, ``imu_stalls``; ``defaults`` for those given without a value), and the
    gaps (start, length in s)."""
    keep = np.ones(len(t), dtype=bool)
    gaps: list[list[float]] = []

    def punch(start: float, length: float) -> None:
        keep[(t > start) & (t < start + length)] = False
        gaps.append([float(start), float(length)])

    if "imu_dropouts" in effects:
        v = effects["imu_dropouts"]
        count = int(defaults["imu_dropouts"] if v is None else v[0])
        punch(float(t[0]), float(rng.uniform(0.012, 0.161)))  # logger start, as PX4's
        for start in np.sort(rng.uniform(0.02, 0.98, count) * duration):
            punch(float(start), float(rng.uniform(0.012, 0.161)))
    if "imu_stalls" in effects:
        v = effects["imu_stalls"]
        for length in ([defaults["imu_stalls"]] if v is None else v):
            punch(float(rng.uniform(0.1, 0.9) * duration), float(length))
    if keep.sum() < 0.5 * len(t):
        raise InputError("the IMU dropouts and stalls remove more than half of the samples; "
                         "give fewer or shorter ones")
    return keep, sorted(gaps)
