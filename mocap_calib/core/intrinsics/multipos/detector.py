"""Static detector of a multi-position session (Tedaldi et al. 2014, as imu_tk).

The threshold has imu_tk's meaning: a sample is static when the norm of the per-axis accel
variance over a centred window ``t_w``, ``|var_w(a)| = sqrt(sum_c var_w(a_c)^2)``, is below
``k |var_init(a)|``, ``k`` times the same norm over the initial static period (imu_tk's
``staticIntervalsDetector`` with ``th_mult * norm_th``; its calibration scans ``k = 2..10``). A
run of static samples at least ``min_interval_s`` long is a static interval. The statistics
come from :mod:`mocap_calib.core.model.rest`. The threshold is a ratio of variances, so the
detector needs no units (raw counts work as they are).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.params import option, option_value
from mocap_calib.core.model import rest
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.policy import gap_threshold
from mocap_calib.errors import InputError, ObservabilityError

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def window_samples(window_s: float, rate_hz: float) -> int:
    """Odd number of samples in a window of ``window_s`` (at least 11, as imu_tk)."""
    w = max(11, int(round(window_s * rate_hz)))
    return w if w % 2 else w + 1


def variance_magnitude(accel: Array, win: int) -> Array:
    """``|var_w(a)|``: norm of the per-axis variance over a centred window (imu_tk's
    "variance magnitude").

    Args:
        accel: (N, 3) accel samples.
        win: odd window length in samples.

    Returns:
        (N,) magnitudes; NaN where the window does not fit (the first and last ``win // 2``).
    """
    return np.linalg.norm(rest.window_variance(accel, win), axis=1)


@dataclass(frozen=True)
class Detector:
    """What the static detector needs, computed once for every threshold multiple."""

    magnitude: Array
    init_mask: NDArray[np.bool_]
    init_magnitude: float
    min_len: int
    after_gap: NDArray[np.bool_] | None = None  # samples that follow an IMU gap

    def intervals(self, k: float) -> IntArray:
        """Static runs; a run ends at an IMU gap (only whole intervals are used)."""
        with np.errstate(invalid="ignore"):
            static = self.magnitude < k * self.init_magnitude
        if self.after_gap is not None:
            static &= ~self.after_gap
        return rest.runs(static, self.min_len)


def check_timing(imu: ImuSamples) -> float:
    """The sample rate, after checking the log's length and timestamps."""
    if len(imu) < 100:
        raise InputError(f"{imu.source}: only {len(imu)} IMU samples; a multi-position session "
                         "has thousands (several minutes at 100-1000 Hz)")
    dt = np.diff(imu.t)
    if np.any(dt <= 0):
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise InputError(f"{imu.source}: timestamps are not strictly increasing at sample "
                         f"{row}; sort the log by time and drop duplicate stamps")
    rate = imu.rate_hz
    if not 10.0 <= rate <= 10000.0:
        raise InputError(f"{imu.source}: sample rate {rate:.3g} Hz is outside 10-10000 Hz; "
                         "check the timestamp unit (nanoseconds expected)")
    return rate


def make_detector(imu: ImuSamples, rate: float, init_static_s: float, window_s: float,
                  min_interval_s: float, names: Mapping[str, str] | None = None,
                  check_gyro: bool = True) -> Detector:
    """Detector of one session; checks that the initial period is static.

    Args:
        names: how the caller spells the options in messages (see ``params.option``).
        check_gyro: also check that the gyro does not turn in the initial period (needs the
            gyro in rad/s; with raw counts the caller checks once the scale is known).
    """
    win = window_samples(window_s, rate)
    init_mask = imu.t - imu.t[0] <= init_static_s
    if init_mask.sum() < 2 * win:
        raise InputError(f"{option_value(names, 'init_static_s', f'{init_static_s:g}')} s is "
                         f"shorter than two detector windows ({2 * win / rate:.1f} s); use "
                         "30-50 s")
    mag = variance_magnitude(imu.accel, win)
    init_mag = float(np.linalg.norm(imu.accel[init_mask].var(axis=0, ddof=1)))
    check_initial_accel(init_mask, mag, init_mag, init_static_s, names)
    if check_gyro:
        check_initial_gyro(imu.gyro[init_mask], rate, init_static_s, names)
    # Floor for quantised, nearly noise-free data: a zero threshold would find nothing static
    # (relative to the signal, so it holds in any unit).
    scale = float(np.median(np.linalg.norm(imu.accel[init_mask], axis=1)))
    init_mag = max(init_mag, 1e-16 * scale**2, 1e-300)
    min_len = max(win // 2, int(round(min_interval_s * rate)))
    after_gap = np.r_[False, np.diff(imu.t) > gap_threshold(imu.t)]
    return Detector(mag, init_mask, init_mag, min_len, after_gap)


def _rest_fix(init_static_s: float, names: Mapping[str, str] | None) -> str:
    return (f"start the recording with the IMU resting still for at least {init_static_s:g} s "
            f"(30-50 s recommended), or pass a shorter {option(names, 'init_static_s')}")


def check_initial_accel(init_mask: NDArray[np.bool_], mag: Array, init_mag: float,
                        init_static_s: float, names: Mapping[str, str] | None = None) -> None:
    """Raise if the accelerometer moves in the initial period: its threshold would then mean
    nothing."""
    inner = mag[init_mask]
    inner = inner[np.isfinite(inner)]
    # Over a static period the windowed variance is the whole period's variance (noise); a
    # motion or a tilt inside it makes the whole-period variance much larger.
    if init_mag > 5.0 * float(np.median(inner)):
        raise ObservabilityError(f"no initial static period: the accelerometer varies within "
                                 f"the first {init_static_s:g} s; "
                                 f"{_rest_fix(init_static_s, names)}")


def check_initial_gyro(gyro_init: Array, rate: float, init_static_s: float,
                       names: Mapping[str, str] | None = None, limit: float = 0.05) -> None:
    """Raise if the gyro turns in the initial period: a rotation that keeps the gravity
    direction (about the vertical) shows only there.

    Args:
        gyro_init: (n, 3) gyro over the initial period, rad/s (or nominal rad/s).
        limit: largest deviation of a 1 s block mean from the median block, rad/s.
    """
    means = rest.block_means(gyro_init, max(1, int(round(rate))))
    spread = float(np.max(np.abs(rest.median_deviation(means))))
    if spread > limit:
        raise ObservabilityError(f"no initial static period: the gyro shows rotation "
                                 f"({np.degrees(spread):.1f} deg/s) within the first "
                                 f"{init_static_s:g} s; {_rest_fix(init_static_s, names)}")


def detect_static_intervals(imu: ImuSamples, threshold_multiple: float, *,
                            init_static_s: float = 30.0, window_s: float = 1.0,
                            min_interval_s: float = 0.5) -> IntArray:
    """Static intervals of a multi-position session for one threshold multiple ``k``.

    Args:
        imu: the session.
        threshold_multiple: ``k`` in ``|var_w(a)| < k |var_init(a)|`` (imu_tk's meaning).
        init_static_s: length of the initial static period.
        window_s: length of the centred variance window ``t_w``.
        min_interval_s: shortest interval kept.

    Returns:
        (n, 2) sample indices ``[start, end]`` (inclusive) of the static intervals.
    """
    rate = check_timing(imu)
    return make_detector(imu, rate, init_static_s, window_s, min_interval_s).intervals(
        threshold_multiple)
