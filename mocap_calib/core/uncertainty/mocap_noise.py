"""The correlated part of the mocap noise, fitted for the check of the answer (not for the
answer itself: :mod:`mocap_calib.core.uncertainty.sensitivity`).

Real mocap noise is far from white: marker sets change with occlusions, and the pose solver and
its filters smooth, so consecutive poses share much of their error. The window filter can model
a fraction of the mocap variance as an AR(1) process (:mod:`mocap_calib.core.position.engine`);
its time constant and fraction are chosen here by the windows' exact likelihood, each candidate
at its own best level. On EuRoC V2_03 the choice moves with the IMU densities and with where
the white solution lands, and fed back into the point estimate it moves it by several mm: so
it is a check, and the point estimate stays white.

The IMU densities are not chosen here. The same likelihood, free to scale the accelerometer's,
prefers 15-20 times the data sheet on EuRoC V2_03 (the in-flight vibration):
``--accel-noise-from-data`` uses that level (:func:`mocap_calib.core.position.settle.
accel_level`); by default the densities stay as given and the sensitivity refits (x3 and x1/3)
carry what not knowing them costs. (With the data's level the lever arm lands 7.8 mm from the
ground-truth-implied one on EuRoC V2_03, where mocap2gt lands 5.3 mm.)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.windows import Theta

Array = NDArray[np.float64]

#: Candidate (time constant s, correlated fraction) pairs; (0, 0) is white noise.
CORRELATION_GRID: tuple[tuple[float, float], ...] = (
    (0.0, 0.0), *((T, rho) for T in (0.03, 0.1, 0.3, 1.0) for rho in (0.5, 0.9, 0.98)))
#: Windows used for the choice (spread over the session): enough for a clear likelihood
#: difference, few enough that the choice costs little on long sessions.
MAX_WINDOWS = 10
#: Mocap rate (Hz) of the likelihood evaluations that choose the model.
RATE_HZ = 30.0


@dataclass(frozen=True)
class CorrelationFit:
    """The chosen mocap noise model and every candidate's -2 log-likelihood (lower: better)."""

    noise: NoiseModel
    candidates: list[dict[str, float]]


def fit_mocap_correlation(problem, th: Theta, grid=CORRELATION_GRID,
                          max_windows: int = MAX_WINDOWS, decimate: bool = True) -> CorrelationFit:
    """Choose the mocap noise's correlation time, fraction and level by the windows' exact
    likelihood.

    The choice runs on a subset of the windows, decimated to about :data:`RATE_HZ` (the
    per-sample white noise and the time constant mean the same at any rate). Each candidate is
    evaluated at the level that makes its whitened innovations average one, then at that
    level halved and doubled around the best candidate. The later rounds of the position stage
    refine the level as usual.

    Args:
        problem: the position stage's :class:`~mocap_calib.core.position.engine.
            PositionProblem` (its noise model, windows and robust weights are used).
        th: parameter values to evaluate at (the current solution).
        grid: candidate (time constant, fraction) pairs.
        max_windows: at most this many windows, spread evenly over the session.
        decimate: at about :data:`RATE_HZ` (else at the windows' own rate).
    """
    win = problem.win
    rate = 1.0 / float(np.median(np.diff(win.tau[0][win.mask[0]])))
    k = max(1, int(rate // RATE_HZ)) if decimate else 1
    sub, th_sub = problem.spread(th, max_windows, k)
    n_dof = 6.0 * float(sub.win.mask.sum())
    base = problem.noise
    models = [replace(base, mocap_noise_corr_time=T, mocap_noise_corr_fraction=rho)
              for T, rho in grid]
    # One pass per candidate: chi2 and log det give the likelihood profiled over a common
    # scale of the innovation covariance (its optimum c = chi2 / n): -2 log L = n log(chi2/n)
    # + log det + n. The mocap noise dominates the innovations, so c is its level.
    parts = sub.likelihoods(th_sub, models)
    interrupt.check()
    chi2 = [float(c.sum()) for c, _ in parts]
    m2ll = [n_dof * np.log(c / n_dof) + float(ld.sum()) + n_dof
            for c, (_, ld) in zip(chi2, parts, strict=True)]
    best = int(np.argmin(m2ll))
    chosen = _scaled(models[best], chi2[best] / n_dof)
    levels = [_scaled(chosen, f) for f in (0.5, 1.0, 2.0)]
    m2ll_lv = [float(c.sum() + ld.sum()) for c, ld in sub.likelihoods(th_sub, levels)]
    rows = [{"time_constant_s": T, "fraction": rho, "level": 1.0, "minus_2_log_likelihood": v}
            for (T, rho), v in zip(grid, m2ll, strict=True)]
    rows += [{"time_constant_s": grid[best][0], "fraction": grid[best][1], "level": f,
              "minus_2_log_likelihood": v} for f, v in zip((0.5, 1.0, 2.0), m2ll_lv, strict=True)]
    return CorrelationFit(levels[int(np.argmin(m2ll_lv))], rows)


def _scaled(nz: NoiseModel, f: float) -> NoiseModel:
    """``nz`` with both mocap variances times ``f``."""
    return replace(nz, mocap_rotation_sigma=nz.mocap_rotation_sigma * np.sqrt(f),
                   mocap_position_sigma=nz.mocap_position_sigma * np.sqrt(f))
