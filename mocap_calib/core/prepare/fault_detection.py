"""Detecting sensor faults in raw streams: dead channels, saturation and frozen (repeated)
samples.

A real sensor never repeats its full reading for long, and never reads exactly its extreme
value many times in a row unless it clips. Each detector works on exact equality of the
numbers as logged (repeats of the same float), so quantised but healthy logs are not flagged:
on EuRoC V2_03 and the BROAD trials no sample is (longest repeat of the full IMU reading: 5
samples, 17 ms; most samples at a channel's extreme: 2).

Users: preparing a session refuses dead sensors (:func:`refuse_dead`) and removes frozen mocap;
the calibration leaves the saturated and frozen IMU spans out
(:mod:`mocap_calib.core.prepare.fault_spans`); the IMU-only tools refuse dead channels and logs
with frozen spans.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.rest import runs
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

AXES = "xyz"
#: A channel reads its extreme value at least this often, in a run of at least this many,
#: before it counts as saturated (clipping, not a peak).
SATURATION_MIN_SAMPLES = 5
SATURATION_MIN_RUN = 3
#: Repeats of the full reading (all channels) that make a frozen span: at least this many
#: samples and this long (s).
FROZEN_MIN_SAMPLES = 10
FROZEN_MIN_S = 0.05
#: Mocap repeats: a pose repeated this many times (and this long, s) is frozen.
MOCAP_FROZEN_SAMPLES = 3
MOCAP_FROZEN_S = 0.03


def dead_channels(gyro: Array, accel: Array) -> list[str]:
    """Channels that read the same value in every sample: ``"gyroscope"`` / ``"accelerometer"``
    when all three are, else ``"gyro z"``-style names. Empty for a healthy log."""
    out = []
    for name, short, x in (("gyroscope", "gyro", gyro), ("accelerometer", "accel", accel)):
        if len(x) < 2:
            continue
        flat = np.ptp(x, axis=0) == 0
        if flat.all():
            out.append(name)
        else:
            out += [f"{short} {AXES[i]}" for i in np.flatnonzero(flat)]
    return out


def describe_dead(gyro: Array, accel: Array, names: list[str]) -> str:
    """``"the accelerometer is dead (every sample reads [0, 0, 0])"``-style text."""
    parts = []
    for n in names:
        if n in ("gyroscope", "accelerometer"):
            x = gyro if n == "gyroscope" else accel
            parts.append(f"the {n} is dead (every sample reads {np.round(x[0], 6).tolist()})")
        else:
            short, axis = n.split()
            x = gyro if short == "gyro" else accel
            parts.append(f"{n} is dead (every sample reads {x[0, AXES.index(axis)]:.6g})")
    return "; ".join(parts)


def saturated(x: Array) -> tuple[Mask, list[str]]:
    """Samples at a channel's extreme value where it clips.

    Args:
        x: (N, 3) one sensor's readings.

    Returns:
        (N,) mask of clipped samples, and the clipping values found (``"x at +2"``).
    """
    bad = np.zeros(len(x), bool)
    found = []
    for i in range(x.shape[1]):
        v = x[:, i]
        for ext in (float(v.max()), float(v.min())):
            at = v == ext
            if at.sum() < SATURATION_MIN_SAMPLES:
                continue
            r = runs(at, 1)
            if (r[:, 1] - r[:, 0] + 1).max() < SATURATION_MIN_RUN:
                continue
            bad |= at
            found.append(f"{AXES[i]} at {ext:+.4g}")
    return bad, found


def frozen(values: Array, rate_hz: float, min_samples: int = FROZEN_MIN_SAMPLES,
           min_s: float = FROZEN_MIN_S) -> Mask:
    """Samples that repeat the previous one exactly (every column), in runs long enough to
    be a frozen stream rather than quantisation or a duplicated sample.

    Args:
        values: (N, c) the stream's readings (all channels, or a pose's numbers).
        rate_hz: its sample rate.

    Returns:
        (N,) True for the repeats (the first sample of a run, the last good one, is kept).
    """
    same = np.zeros(len(values), bool)
    if len(values) < 2:
        return same
    same[1:] = np.all(values[1:] == values[:-1], axis=1)
    need = max(min_samples, int(np.ceil(min_s * rate_hz)))
    out = np.zeros(len(values), bool)
    for a, b in runs(same, need):
        out[a:b + 1] = True
    return out


@dataclass(frozen=True)
class ImuFaults:
    """Faulty IMU samples and what they are.

    Attributes:
        bad: (N,) samples to leave out.
        what: one phrase per fault kind, e.g. ``"gyro saturated (x at +2, ...) in 812 samples"``.
    """

    bad: Mask
    what: list[str]

    @property
    def any(self) -> bool:
        return bool(self.bad.any())


def imu_faults(gyro: Array, accel: Array, rate_hz: float) -> ImuFaults:
    """Saturated and frozen samples of an IMU log."""
    bad = np.zeros(len(gyro), bool)
    what = []
    for name, x in (("gyro", gyro), ("accelerometer", accel)):
        m, found = saturated(x)
        if m.any():
            bad |= m
            what.append(f"{name} saturated ({', '.join(found)}) in {int(m.sum())} samples")
    fz = frozen(np.hstack([gyro, accel]), rate_hz)
    if fz.any():
        bad |= fz
        what.append(f"IMU frozen (the same sample repeated) for {fz.sum() / rate_hz:.3g} s")
    return ImuFaults(bad, what)


def refuse_dead(imu: ImuSamples, mocap: MocapPoses) -> None:
    """Raise when an IMU channel is dead or the mocap pose never changes."""
    dead = dead_channels(imu.gyro, imu.accel)
    if dead:
        raise InputError(f"{imu.source}: {describe_dead(imu.gyro, imu.accel, dead)}; check the "
                         "sensor and the column map (a calibration needs every channel)")
    m = np.hstack([mocap.quat_wxyz, mocap.position])
    if len(m) > 1 and np.all(np.ptp(m, axis=0) == 0):
        raise InputError(f"{mocap.source}: the mocap stream is frozen (every pose is the same); "
                         "check that the rigid body was tracked during the recording")


def frozen_mocap(mocap: MocapPoses) -> Mask:
    """Mocap samples that repeat the pose before them (a frozen stream), to be removed."""
    rate = mocap.rate_hz or 1.0
    bad = frozen(np.hstack([mocap.quat_wxyz, mocap.position]), rate, MOCAP_FROZEN_SAMPLES,
                 MOCAP_FROZEN_S)
    if bad.mean() > 0.9:
        raise InputError(f"{mocap.source}: the mocap stream is frozen (the same pose repeated) "
                         f"for {bad.sum() / rate:.3g} s of {mocap.duration:.3g} s; check that "
                         "the rigid body was tracked during the recording")
    return bad
