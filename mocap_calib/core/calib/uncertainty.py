"""Uncertainty of the position stage: marginal covariances, the session-mean bias, and which
parameters the data did not determine."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.calib.graph import linear_combination_covariance
from mocap_calib.core.calib.windows import Windows
from mocap_calib.core.model.ranges import RANGE_SIGMA, UNOBSERVABLE_RATIO
from mocap_calib.core.model.types import NoiseModel

Array = NDArray[np.float64]


def key_knot(w: int) -> int:
    """GTSAM key of window ``w``'s bias knot (gyro + accel, Vector6)."""
    return gtsam.symbol("b", w)


@dataclass
class PositionUncertainty:
    """Covariances at the solution.

    Attributes:
        cov: per parameter block, its marginal covariance (tangent space); ``gyro_bias`` and
            ``accel_bias`` are those of the session-mean bias.
        knot_sigma: (W, 6) marginal 1-sigma of each bias knot.
        bias_mean: (6,) session-mean gyro and accel bias.
    """

    cov: dict[str, Array]
    knot_sigma: Array
    bias_mean: Array


def mean_bias_weights(windows: Windows) -> Array:
    """(W,) weights of the knots in the session-mean bias: each window's mean bias is its knot
    interpolated towards the next one, weighted by the window's length."""
    W = windows.count
    starts, lengths = windows.start, windows.end - windows.start
    coef = np.zeros((W, W))
    for w in range(W):
        if w + 1 < W:
            a = 0.5 * lengths[w] / max(starts[w + 1] - starts[w], 1e-9)
            coef[w, w] = 1.0 - a
            coef[w, w + 1] = a
        else:
            coef[w, w] = 1.0
    return (lengths / lengths.sum()) @ coef


def position_covariances(graph: gtsam.NonlinearFactorGraph, sol: gtsam.Values,
                         block_keys: dict[str, int], windows: Windows, knots: Array,
                         noise: NoiseModel) -> PositionUncertainty:
    """Marginals of every block, of every knot, and the session-mean bias covariance."""
    W = windows.count
    marg = gtsam.Marginals(graph, sol)
    cov = {name: np.asarray(marg.marginalCovariance(key)) for name, key in block_keys.items()}
    knot_sigma = np.stack([np.sqrt(np.diag(marg.marginalCovariance(key_knot(w))))
                           for w in range(W)])
    c_mean = mean_bias_weights(windows)
    Cm = np.kron(c_mean[None, :], np.eye(6))  # (6, 6W)
    bias_mean = Cm @ knots.reshape(-1)
    combo = {key_knot(w): Cm[:, 6 * w:6 * w + 6] for w in range(W)}
    knot_part = linear_combination_covariance(graph, sol, combo)
    # Random-walk wander inside each window around the interpolation (Brownian bridge).
    lengths = windows.end - windows.start
    weights_w = lengths / lengths.sum()
    bridge = (weights_w**2 * lengths).sum() / 12.0
    rw2 = np.r_[np.full(3, noise.gyroscope_random_walk**2),
                np.full(3, noise.accelerometer_random_walk**2)]
    bias_cov = knot_part + np.diag(rw2 * bridge)
    cov["gyro_bias"] = bias_cov[0:3, 0:3]
    cov["accel_bias"] = bias_cov[3:6, 3:6]
    return PositionUncertainty(cov, knot_sigma, bias_mean)


def unobservable_blocks(cov: dict[str, Array]) -> dict[str, str]:
    """Blocks whose posterior sigma is not well below their range prior, with the reason."""
    unobservable: dict[str, str] = {}
    for name, C in cov.items():
        prior_sig = RANGE_SIGMA.get(name)
        if prior_sig is None:
            continue
        sig = np.sqrt(np.maximum(np.diag(C), 0.0))
        bad = sig > UNOBSERVABLE_RATIO * prior_sig
        if np.any(bad):
            axes = ", ".join(str(i) for i in np.flatnonzero(bad))
            unobservable[name] = (f"not determined by the motion (component {axes}: sigma "
                                  f"{sig[bad].max():.3g} vs prior range {prior_sig:.3g}); "
                                  "excite it more or give a prior")
    return unobservable
