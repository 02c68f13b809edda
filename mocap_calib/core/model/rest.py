"""Rest (static) detection from IMU samples: one set of statistics for every tool that asks
"is the IMU still here?".

Two statistics, both computed without loops:

* the *local variance* of the accelerometer over a centred window (imu_tk's static detector,
  Tedaldi et al. 2014): its norm ``|var_w(a)|`` against a multiple of the same norm over a
  period known to be static, or against the log's own noise floor;
* *block means* of the gyro over ~1 s blocks and their deviation from the median block: a
  rotation (even one that keeps the gravity direction, invisible to the accelerometer) moves
  the block means by far more than noise.

Users: the multi-position static detector and its initial-period check
(:mod:`mocap_calib.core.intrinsics.multipos.detector`), the Allan log's static check
(:mod:`mocap_calib.core.intrinsics.allan`), the drift check's "at rest" test
(:func:`window_rest`), and the calibration's "nearly static session" check
(:func:`gyro_activity`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def window_variance(x: Array, win: int) -> Array:
    """Per-axis sample variance (``ddof=1``) over a centred window of ``win`` samples.

    Args:
        x: (N, c) samples.
        win: odd window length in samples.

    Returns:
        (N, c) variances; NaN where the window does not fit (the first and last ``win // 2``).
    """
    n, c = x.shape
    out = np.full((n, c), np.nan)
    if n < win:
        return out
    # Centre the data first so the cumulative sums do not lose the variance to cancellation.
    y = x - np.median(x, axis=0)
    c1 = np.concatenate([np.zeros((1, c)), np.cumsum(y, axis=0)])
    c2 = np.concatenate([np.zeros((1, c)), np.cumsum(y * y, axis=0)])
    s1 = c1[win:] - c1[:-win]
    s2 = c2[win:] - c2[:-win]
    h = win // 2
    out[h:n - h] = np.clip((s2 - s1 * s1 / win) / (win - 1), 0.0, None)
    return out


def runs(mask: NDArray[np.bool_], min_len: int) -> IntArray:
    """``[start, end]`` (inclusive sample indices) of the runs of True at least ``min_len``
    long, as an (n, 2) array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    keep = ends - starts + 1 >= min_len
    return np.stack([starts[keep], ends[keep]], axis=1).astype(np.int64)


def _blocks(x: Array, block: int) -> Array:
    nb = len(x) // block
    return x[:nb * block].reshape(nb, block, x.shape[1])


def block_means(x: Array, block: int) -> Array:
    """(nb, c) means of consecutive blocks of ``block`` samples (a partial last block is
    dropped)."""
    return _blocks(x, block).mean(axis=1)


def block_variances(x: Array, block: int) -> Array:
    """(nb, c) variances (``ddof=0``) of consecutive blocks of ``block`` samples."""
    return _blocks(x, block).var(axis=1)


def median_deviation(means: Array) -> Array:
    """(nb, c) deviation of every block mean from the median block (per axis): what a rotation
    moves and noise does not."""
    return means - np.median(means, axis=0)


@dataclass(frozen=True)
class WindowRest:
    """Whether a short window is at rest, and the figures that decided it.

    Attributes:
        at_rest: both figures below their limits.
        accel_std: largest per-axis standard deviation of the specific force (input units).
        rate: norm of the mean angular rate (input units).
    """

    at_rest: bool
    accel_std: float
    rate: float


def window_rest(accel: Array, gyro: Array, accel_std_max: float, rate_max: float
                ) -> WindowRest:
    """Rest test of one window: the specific force does not vary and the (bias-corrected)
    rate does not turn.

    Args:
        accel: (n, 3) specific force over the window.
        gyro: (n, 3) angular rate over the window, bias removed.
        accel_std_max: limit on the largest per-axis standard deviation.
        rate_max: limit on the norm of the mean rate.
    """
    std = float(np.max(accel.std(axis=0)))
    rate = float(np.linalg.norm(gyro.mean(axis=0)))
    return WindowRest(std <= accel_std_max and rate <= rate_max, std, rate)


def gyro_activity(gyro: Array, percentile: float = 90.0) -> float:
    """How much a log turns: the given percentile of ``|w - median(w)|`` (rad/s for a gyro in
    rad/s). A nearly static log stays below ~0.1 rad/s; a calibration flight is far above."""
    speed = np.linalg.norm(gyro - np.median(gyro, axis=0), axis=1)
    return float(np.percentile(speed, percentile))
