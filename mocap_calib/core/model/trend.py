"""First-order trends over earlier results: the prior of a new session from a history.

Every column (one parameter component) gets a weighted straight line through its earlier values
against time; the line's value and standard error at the new session's time are the prediction.
Used by the calibration priors (:mod:`mocap_calib.core.result.priors`) and the multi-position
priors (:mod:`mocap_calib.core.intrinsics.multipos.prior`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def extrapolate_trend(t: Array, y: Array, sigma: Array, t_at: float) -> tuple[Array, Array]:
    """Weighted first-order fit per column of ``y`` (rows: results), predicted at ``t_at``.

    Entries whose value or sigma is not finite, or whose sigma is not positive, carry no
    weight. A column with one usable time (or all at the same time) gets the weighted mean.
    With more than two points the covariance of the line is scaled up (never down) by the
    fit's reduced chi-square, so a history that scatters more than its sigmas say widens the
    prediction.

    Args:
        t: (n,) times of the results (any common origin and unit).
        y: (n, c) values.
        sigma: (n, c) their 1-sigma.
        t_at: time to predict at (same origin and unit).

    Returns:
        (c,) predicted values and (c,) their 1-sigma (``inf`` where a column has no data).
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    out_v = np.zeros(y.shape[1])
    out_s = np.full(y.shape[1], np.inf)
    for c in range(y.shape[1]):
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(y[:, c]) & np.isfinite(sigma[:, c]) & (sigma[:, c] > 0)
        if not ok.any():
            continue
        tc, yc, sc = t[ok], y[ok, c], sigma[ok, c]
        w = 1.0 / sc**2
        if len(tc) == 1 or np.ptp(tc) == 0:
            # No time spread: the best one can do is the weighted mean.
            out_v[c] = np.sum(w * yc) / np.sum(w)
            out_s[c] = 1.0 / np.sqrt(np.sum(w))
            continue
        # Centred on the weighted mean time: the normal matrix is then well conditioned.
        t_ref = float(np.sum(w * tc) / np.sum(w))
        A = np.stack([np.ones_like(tc), tc - t_ref], axis=1)
        N = A.T @ (A * w[:, None])
        cov = np.linalg.inv(N)
        coef = cov @ (A.T @ (w * yc))
        dof = len(tc) - 2
        if dof > 0:
            chi2 = float(np.sum(w * (yc - A @ coef) ** 2)) / dof
            cov = cov * max(1.0, chi2)
        a = np.array([1.0, t_at - t_ref])
        out_v[c] = float(a @ coef)
        out_s[c] = float(np.sqrt(a @ cov @ a))
    return out_v, out_s
