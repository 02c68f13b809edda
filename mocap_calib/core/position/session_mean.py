"""A take's session-mean bias and its uncertainty against the bias's true time mean.

The reported session mean is the knots' time-weighted mean (each window's knot interpolated
towards the next). What it is compared with is the time mean of a bias that wanders (the bias
random walk), which the data pin better than the bias at the knots' instants: the drift of the
position tells the mean bias more than when it was where. So the covariance is that of the
time mean's posterior plus the reported mean's distance from it:

- the posterior: each window's filter starts its bias at the knot and lets it wander; six more
  states carry the time integral of its bias error, in one filter pass at the solution, and the
  integral is conditioned on where the window's end bias meets the next knot (the end rows).
  The time mean is the knots times the windows' lengths plus the integrals, over the session's
  time; its covariance is the parameters' (through its Jacobian, ``d_window``/``d_next``) plus
  the integrals' own given every parameter (``cov_given``);
- the distance: the knots' mean is not the posterior mean, and its error is the sum of both.

Why not report the posterior mean itself: it rests on the accelerometer's white-noise level,
which a 90 s session identifies only to +-40 % (5-95 %, realistic simulator); the knots' mean
does not, and the distance term grows where the two disagree (docs/validation.md, sigma study).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.windows import EvalOut, Windows

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SessionMean:
    """A take's session-mean bias (gyro then accel, rad/s and m/s^2): the time mean's posterior
    as a function of the knots and the windows' columns, linearised at a filter pass, and the
    reported mean's weights.

    Attributes:
        span_s: (W,) each window's length (s), the weights of its knot.
        correction: (6,) the time mean of the filters' bias errors over the windows (added to
            the knots' time-weighted mean).
        d_window: (W, 6, p) the mean's derivative by each window's Jacobian columns (the
            layout's order, the window's own knot last).
        d_next: (W, 6, 6) its derivative by the knot after each window (zero after the last).
        cov_given: (6, 6) the time mean's covariance given every parameter and knot.
        knot_weights: (W,) the knots' weights in the reported mean.
    """

    span_s: Array
    correction: Array
    d_window: Array
    d_next: Array
    cov_given: Array
    knot_weights: Array

    def value(self, knots: Array) -> Array:
        """(6,) the time mean's posterior mean with the knots ``knots`` (W, 6)."""
        return self.span_s @ knots / self.span_s.sum() + self.correction

    def knots_mean(self, knots: Array) -> Array:
        """(6,) the reported session mean: the knots' weighted mean."""
        return self.knot_weights @ knots


def knot_weights(windows: Windows) -> Array:
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


def end_covariance(term_P: Array, windows: Windows, noise: NoiseModel) -> Array:
    """(W-1, 6, 6) the covariance of each window's end bias (the filter's) plus the walk over
    the gap to the next window's start: how well the next knot is predicted."""
    q = np.r_[np.full(3, noise.gyroscope_random_walk**2),
              np.full(3, noise.accelerometer_random_walk**2)]
    gap = np.maximum(windows.start[1:] - windows.end[:-1], 0.0)
    return (term_P[:-1] + q[None, :, None] * np.eye(6)[None] * gap[:, None, None]
            + 1e-14 * np.eye(6))


def session_mean(out: EvalOut, knots: Array, windows: Windows,
                 noise: NoiseModel) -> SessionMean:
    """The session mean from a filter pass with the bias integrals (``out.int_X``,
    ``out.int_P``) at the knots ``knots`` (W, 6)."""
    if out.int_X is None or out.int_P is None or out.term_X is None or out.term_P is None:
        raise ValueError("session_mean needs a filter pass with the bias integrals")
    W, _, p1 = out.int_X.shape
    p = p1 - 1
    span = np.asarray(windows.end - windows.start, dtype=float)
    T = float(span.sum())
    iX, iP, iPb = out.int_X, out.int_P[:, :, 0:6], out.int_P[:, :, 6:12]
    tX = out.term_X
    # Gain of each integral on its window's end-row residual (the next knot minus the knot and
    # the filter's end bias error), and what it leaves of the integral's covariance.
    K = np.zeros((W, 6, 6))
    if W > 1:
        S = end_covariance(out.term_P, windows, noise)
        K[:-1] = np.swapaxes(np.linalg.solve(S, np.swapaxes(iPb[:-1], 1, 2)), 1, 2)
    e_r = np.zeros((W, 6))
    e_r[:-1] = knots[1:] - knots[:-1] - tX[:-1, :, p]
    correction = (iX[:, :, p] + np.einsum("wij,wj->wi", K, e_r)).sum(axis=0) / T
    d_window = (iX[:, :, :p] - K @ tX[:, :, :p]) / T
    d_window[:, :, p - 6:] += (span[:, None, None] * np.eye(6) - K) / T
    cov_given = (iP - K @ np.swapaxes(iPb, 1, 2)).sum(axis=0) / T**2
    return SessionMean(span, correction, d_window, K / T, 0.5 * (cov_given + cov_given.T),
                       knot_weights(windows))
