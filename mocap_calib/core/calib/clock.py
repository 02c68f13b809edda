"""Coarse clock alignment: cross-correlate angular speed from the gyro and from the mocap.

The angular speed ``|w|`` does not depend on the unknown IMU-to-marker rotation, so the two
streams can be aligned before anything else is known. The correlation runs over every lag the
two recordings allow, so offsets of any size work, including clocks from different epochs whose
raw stamps do not overlap at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from mocap_calib.core.model import so3
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CoarseOffset:
    """Result of the coarse search.

    Attributes:
        time_offset: ``t_d`` (s) relative to the raw stamps: an IMU sample stamped ``t``
            (absolute) was taken at mocap absolute time ``t + t_d``.
        peak: normalised correlation at the peak (1 = identical shapes).
        second_peak: best normalised correlation further than 1 s from the peak.
        resolution: grid spacing used (s).
    """

    time_offset: float
    peak: float
    second_peak: float
    resolution: float


def mocap_angular_speed(t: Array, R: Array) -> tuple[Array, Array]:
    """Angular speed (rad/s) between consecutive mocap samples, at interval midpoints."""
    dR = np.einsum("nji,njk->nik", R[:-1], R[1:])
    dt = np.diff(t)
    speed = np.linalg.norm(so3.log(dR), axis=1) / dt
    return 0.5 * (t[1:] + t[:-1]), speed


def _resample(t: Array, y: Array, dt: float, gap: float) -> tuple[float, Array]:
    """Resample onto a uniform grid; samples inside gaps are set to the mean (no signal)."""
    grid = np.arange(t[0], t[-1], dt)
    out = np.interp(grid, t, y)
    idx = np.searchsorted(t, grid)
    idx = np.clip(idx, 1, len(t) - 1)
    in_gap = (t[idx] - t[idx - 1]) > gap
    z = out - out[~in_gap].mean() if np.any(~in_gap) else out - out.mean()
    z[in_gap] = 0.0
    return float(grid[0]), z


def coarse_offset_arrays(u: Array, gyro: Array, tau: Array, R_WM: Array, clock_shift: float,
                         rate_hz: float = 200.0) -> CoarseOffset:
    """Find ``t_d`` by cross-correlating gyro and mocap angular speed over all lags.

    IMU times ``u`` and mocap times ``tau`` are relative to their own origins,
    ``clock_shift = (origin_imu - origin_mocap) * 1e-9``."""
    dt = 1.0 / rate_hz
    shift = -clock_shift
    t_m, s_m = mocap_angular_speed(tau, R_WM)
    # A median filter removes single-sample spikes (a marker swap missed by the screen); a
    # short Savitzky-Golay filter then smooths the noise of differentiated attitudes.
    if len(s_m) > 7:
        s_m = signal.savgol_filter(signal.medfilt(s_m, 5), 5, 2)
    s_i = np.linalg.norm(gyro, axis=1)
    gap_m = 5.0 * np.median(np.diff(t_m))
    gap_i = 5.0 * np.median(np.diff(u))
    start_i, x = _resample(u, s_i, dt, gap_i)
    start_m, y = _resample(t_m, s_m, dt, gap_m)
    if np.std(x) < 0.05 or np.std(y) < 0.05:
        raise ObservabilityError(
            "too little rotation to align the clocks (angular speed varies by less than "
            "0.05 rad/s); record a session with the body rotating, or give --time-offset")
    # Full cross-correlation, normalised by the overlap so short overlaps are not favoured.
    num = signal.correlate(y, x, mode="full", method="fft")
    ones_x = np.ones_like(x)
    ones_y = np.ones_like(y)
    n_overlap = signal.correlate(ones_y, ones_x, mode="full", method="fft")
    sx2 = signal.correlate(ones_y, x * x, mode="full", method="fft")
    sy2 = signal.correlate(y * y, ones_x, mode="full", method="fft")
    min_overlap = max(int(5.0 / dt), int(0.2 * min(len(x), len(y))))
    valid = n_overlap > min_overlap
    denom = np.sqrt(np.maximum(sx2 * sy2, 1e-300))
    corr = np.where(valid, num / denom, -np.inf)
    lags = np.arange(-(len(x) - 1), len(y))
    k = int(np.argmax(corr))
    peak = float(corr[k])
    # Parabolic refinement of the peak.
    frac = 0.0
    if 0 < k < len(corr) - 1 and np.isfinite(corr[k - 1]) and np.isfinite(corr[k + 1]):
        a, b, c = corr[k - 1], corr[k], corr[k + 1]
        den = a - 2 * b + c
        if den < 0:
            frac = 0.5 * (a - c) / den
    lag_s = (lags[k] + frac) * dt
    far = np.abs(lags - lags[k]) * dt > 1.0
    second = float(np.max(corr[far & valid])) if np.any(far & valid) else -1.0
    if not peak > 0.3:
        raise ObservabilityError(
            f"could not align the clocks: the best correlation of angular speed is {peak:.2f}; "
            "check that the IMU and mocap files are from the same session")
    # y(grid_m[j]) ~ x(grid_i[j - lag]) : mocap time start_m + j dt (mocap clock, relative to
    # the IMU origin after adding ``shift``) equals IMU time start_i + (j - lag) dt.
    t_d = (start_m + shift) - start_i + lag_s
    return CoarseOffset(float(t_d), peak, second, dt)
