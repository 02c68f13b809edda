"""Faults of the simulated streams, not of the IMU model: mocap dropouts and marker swaps, and
the gaps flight controllers' logs have (dropped samples after logger buffer overruns, stalls).

:data:`FAULTS` is their registry (what ``--effect NAME[=VALUE]`` accepts beside the effects of
:mod:`mocap_calib.core.model.effects`); the functions below inject them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.errors import InputError

Array = NDArray[np.float64]

Injected = dict[str, list[float] | None]


@dataclass(frozen=True)
class Fault:
    """A stream fault: its stream, what a bare ``NAME`` injects, what ``VALUE`` means.

    ``events``: the value is a number of events (a whole number, 0-1000); otherwise it is a
    list of ``counts`` positive lengths in s.
    """

    stream: Literal["mocap", "imu"]
    default: float
    help: str
    events: bool = True
    counts: tuple[int, ...] = (1,)


FAULTS: dict[str, Fault] = {
    "mocap_dropouts": Fault("mocap", 5, "number of mocap gaps (0.05-1 s each, rows removed)"),
    "mocap_outliers": Fault("mocap", 5, "number of marker-swap events (1-4 samples jump by "
                            "3-10 cm, 5-30 deg)"),
    "imu_dropouts": Fault("imu", 30, "number of IMU gaps of 12-161 ms (logger buffer overruns, "
                          "as PX4 logs have them), plus one after the first sample"),
    "imu_stalls": Fault("imu", 0.5, "lengths of IMU stalls in s (1-5 values, e.g. 0.5,3)",
                        events=False, counts=(1, 2, 3, 4, 5)),
}


def _count(effects: Injected, name: str) -> int:
    v = effects[name]
    return int(FAULTS[name].default if v is None else v[0])


def mocap_outliers(rng: np.random.Generator, effects: Injected, R: Array, p: Array
                   ) -> list[int]:
    """Marker swaps: runs of 1-4 rows jump by 3-10 cm and 5-30 deg (``R``, ``p`` changed in
    place); the rows changed."""
    rows_out: list[int] = []
    if "mocap_outliers" not in effects:
        return rows_out
    n = len(p)
    count = _count(effects, "mocap_outliers")
    if count > (n - 20) // 10:
        raise InputError(f"mocap_outliers={count}: too many for {n} mocap samples; "
                         f"use at most {(n - 20) // 10}")
    for start in np.sort(rng.choice(np.arange(10, n - 10), size=count, replace=False)):
        length = int(rng.integers(1, 5))
        jump = rng.normal(size=3)
        jump *= rng.uniform(0.03, 0.10) / np.linalg.norm(jump)
        axis = rng.normal(size=3)
        rot = so3.exp(np.radians(rng.uniform(5, 30)) * axis / np.linalg.norm(axis))
        rows = np.arange(start, min(start + length, n))
        p[rows] += jump
        R[rows] = R[rows] @ rot
        rows_out.extend(int(r) for r in rows)
    return rows_out


def mocap_dropouts(rng: np.random.Generator, effects: Injected, t: Array, duration: float
                   ) -> tuple[NDArray[np.bool_], list[list[float]]]:
    """Mocap rows kept (stamps ``t``) after gaps of 0.05-1 s, and the gaps (start, length)."""
    keep = np.ones(len(t), dtype=bool)
    gaps: list[list[float]] = []
    if "mocap_dropouts" in effects:
        for start in np.sort(rng.uniform(0.05, 0.95, _count(effects, "mocap_dropouts"))
                             * duration):
            length = rng.uniform(0.05, 1.0)
            keep &= ~((t >= start) & (t < start + length))
            gaps.append([float(start), float(length)])
    return keep, gaps


def imu_gaps(rng: np.random.Generator, duration: float, t: Array, effects: Injected
             ) -> tuple[NDArray[np.bool_], list[list[float]]]:
    """IMU samples (times ``t``) kept after the logging faults in ``effects``
    (``imu_dropouts``, ``imu_stalls``), and the gaps (start, length in s)."""
    keep = np.ones(len(t), dtype=bool)
    gaps: list[list[float]] = []

    def punch(start: float, length: float) -> None:
        keep[(t > start) & (t < start + length)] = False
        gaps.append([float(start), float(length)])

    if "imu_dropouts" in effects:
        punch(float(t[0]), float(rng.uniform(0.012, 0.161)))  # logger start, as PX4's
        for start in np.sort(rng.uniform(0.02, 0.98, _count(effects, "imu_dropouts"))
                             * duration):
            punch(float(start), float(rng.uniform(0.012, 0.161)))
    if "imu_stalls" in effects:
        v = effects["imu_stalls"]
        for length in ([FAULTS["imu_stalls"].default] if v is None else v):
            punch(float(rng.uniform(0.1, 0.9) * duration), float(length))
    if keep.sum() < 0.5 * len(t):
        raise InputError("the IMU dropouts and stalls remove more than half of the samples; "
                         "give fewer or shorter ones")
    return keep, sorted(gaps)
