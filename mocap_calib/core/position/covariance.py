"""Uncertainty of the position stage: marginal covariances, the session-mean bias, and which
parameters the data did not determine.

Two covariances are computed. The model-based one (``H^-1``, GTSAM's marginals) is right when
the noise model is. The sandwich ``H^-1 B H^-1`` takes the spread of the data's own scores
instead: ``B`` sums, over blocks of about a second of mocap samples, the outer products of
each block's whitened score ``J^T r``, plus the information of the factors that are not data
(bias random walk, priors). When the model is right, ``B`` estimates ``H`` and both agree; when
the residuals hold structure the model lacks (correlated noise of another shape, an effect not
in the model), the blocks' scores scatter more than the model says and the sandwich grows with
them. The reported sigma of every component is the larger of the two.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.graph import (
    information_matrix,
    linear_combination_covariance,
    marginals,
)
from mocap_calib.core.model.ranges import RANGE_SIGMA, UNOBSERVABLE_RATIO
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.windows import Windows

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
        cov_model: the model-based covariances (``cov`` before the sandwich).
        robust_ratio: per block, the sandwich's sigma over the model's, per component.
    """

    cov: dict[str, Array]
    knot_sigma: Array
    bias_mean: Array
    cov_model: dict[str, Array] = field(default_factory=dict)
    robust_ratio: dict[str, list[float]] = field(default_factory=dict)


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
                         noise: NoiseModel, scores: Array | None = None,
                         score_blocks: list[tuple[str, int]] | None = None,
                         n_window_factors: int = 0) -> PositionUncertainty:
    """Marginals of every block, of every knot, and the session-mean bias covariance.

    Args:
        graph, sol: the position graph and its solution.
        block_keys: parameter block name -> key.
        windows, knots, noise: the stage's windows, bias knots and noise model.
        scores: (W, B, p) per-block whitened scores of the window factors (sandwich), with
            ``score_blocks`` the (name, dimension) of their columns' parameter blocks in order
            (the window's knot last, not listed); without them only the model-based covariance
            is computed.
        n_window_factors: the window factors are the graph's first this many factors.
    """
    W = windows.count
    marg = marginals(graph, sol)
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
    unc = PositionUncertainty(cov, knot_sigma, bias_mean, dict(cov), {})
    if scores is not None and score_blocks is not None:
        robust = _sandwich(graph, sol, block_keys, combo, scores, score_blocks, n_window_factors)
        robust["gyro_bias"] = robust["gyro_bias"] + np.diag(rw2[0:3] * bridge)
        robust["accel_bias"] = robust["accel_bias"] + np.diag(rw2[3:6] * bridge)
        unc.cov, unc.robust_ratio = _larger(cov, robust)
    return unc


def _sandwich(graph: gtsam.NonlinearFactorGraph, sol: gtsam.Values, block_keys: dict[str, int],
              combo: dict[int, Array], scores: Array, score_blocks: list[tuple[str, int]],
              n_window_factors: int) -> dict[str, Array]:
    """``H^-1 B H^-1`` for every parameter block and for the session-mean bias."""
    from scipy.sparse.linalg import splu

    H, offsets, n = information_matrix(graph, sol)
    other = gtsam.NonlinearFactorGraph()
    for i in range(n_window_factors, graph.size()):
        other.add(graph.at(i))
    H_other, _, _ = information_matrix(other, sol, offsets, n)
    # Targets: every block's tangent components, then the six mean-bias components.
    dims = dict(score_blocks)
    q = sum(dims.values()) + 6
    E = np.zeros((n, q))
    col = 0
    spans: dict[str, slice] = {}
    for name, key in block_keys.items():
        E[offsets[key]:offsets[key] + dims[name], col:col + dims[name]] = np.eye(dims[name])
        spans[name] = slice(col, col + dims[name])
        col += dims[name]
    for key, Ck in combo.items():
        E[offsets[key]:offsets[key] + 6, col:col + 6] = Ck.T
    Z = splu(H).solve(E)  # H^-1 E
    meat = Z.T @ (H_other @ Z)
    glob = np.concatenate([offsets[block_keys[name]] + np.arange(d) for name, d in score_blocks])
    # Each block's score mapped to the targets. Centred: at the optimum they sum to (about)
    # zero anyway, and a refit evaluated near, not at, its optimum keeps its mean out of B.
    T = np.concatenate([scores[w] @ Z[np.concatenate([glob, offsets[key_knot(w)] + np.arange(6)])]
                        for w in range(scores.shape[0])])
    T = T[np.any(T != 0.0, axis=1)]  # padding blocks of short windows hold no samples
    if len(T) > 1:
        T = (T - T.mean(axis=0)) * np.sqrt(len(T) / (len(T) - 1.0))
    meat += T.T @ T
    out = {name: meat[sl, sl] for name, sl in spans.items()}
    out["gyro_bias"] = meat[col:col + 3, col:col + 3]
    out["accel_bias"] = meat[col + 3:col + 6, col + 3:col + 6]
    return out


def _larger(model: dict[str, Array], robust: dict[str, Array]
            ) -> tuple[dict[str, Array], dict[str, list[float]]]:
    """Per block: the model covariance with each component's variance raised to the sandwich's
    where that is larger (correlations kept), and the sigma ratios sandwich / model."""
    out, ratio = {}, {}
    for name, C in model.items():
        if name not in robust:
            out[name] = C
            continue
        v_m = np.maximum(np.diag(C), 1e-300)
        r = np.sqrt(np.maximum(np.diag(robust[name]), 0.0) / v_m)
        s = np.maximum(1.0, r)
        out[name] = C * np.outer(s, s)
        ratio[name] = [round(float(x), 3) for x in r]
    return out, ratio


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
