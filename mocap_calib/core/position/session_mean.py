"""A take's session-mean bias from its windows' filters, and how it depends on the parameters.

Each window's filter starts its bias at the window's knot and lets it wander (the bias random
walk); the data it sees tell where the bias went. The session mean is the time mean of that
bias: every window's knot times its length plus the time integral of its filter's bias error,
which the filter carries as six more states in one pass at the solution. Where a window's end
bias meets the next knot (the end rows), the integral is conditioned on that meeting too. So the
mean is what the data say of the bias over the whole session, not of the bias at the knots'
instants: the data pin the former better (a drift of the position tells the mean bias, less
when it was there), and its covariance is the knots' and the parameters' through the mean's
Jacobian plus the integrals' own, given all parameters.
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
    """A take's session-mean bias (gyro then accel, rad/s and m/s^2) as a function of its knots
    and the windows' columns, linearised at a filter pass.

    Attributes:
        span_s: (W,) each window's length (s), the weights of its knot.
        correction: (6,) the time mean of the filters' bias errors over the windows (added to
            the knots' time-weighted mean).
        d_window: (W, 6, p) the mean's derivative by each window's Jacobian columns (the
            layout's order, the window's own knot last).
        d_next: (W, 6, 6) its derivative by the knot after each window (zero after the last).
        cov_given: (6, 6) the mean's covariance given every parameter and knot.
    """

    span_s: Array
    correction: Array
    d_window: Array
    d_next: Array
    cov_given: Array
    end_white: Array | None = None

    def value(self, knots: Array) -> Array:
        """(6,) the session mean with the knots ``knots`` (W, 6)."""
        return self.span_s @ knots / self.span_s.sum() + self.correction


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
    ew = None
    if W > 1:
        L = np.linalg.cholesky(S)
        ew = np.linalg.solve(L, e_r[:-1, :, None])[..., 0]
    return SessionMean(span, correction, d_window, K / T, 0.5 * (cov_given + cov_given.T), ew)
