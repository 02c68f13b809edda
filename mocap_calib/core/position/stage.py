"""Stage 3, position factors: refine every parameter jointly on a GTSAM factor graph.

Variables: ``R_MI`` (Rot3), ``p_MI`` (Point3), the gravity direction (Unit3), the clock offset
and ``|g|`` when the model estimates them, one vector per IMU-side effect, and one bias knot
(gyro + accel, Vector6) at the start of every window. Factors: one window factor per window
(:mod:`mocap_calib.core.position.engine`, evaluated together), a random-walk between-factor for
consecutive knots, weak range priors that keep the system well posed (a parameter whose
uncertainty they dominate is reported as unobservable), and user priors. Mocap outliers are
handled per sample by a redescending kernel on the whitened innovation (iteratively
re-weighted; weights are frozen during each LM run so LM sees one fixed cost).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.graph import require_converged, run_lm
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.covariance import (
    PositionUncertainty,
    mean_bias_weights,
    position_covariances,
    unobservable_blocks,
)
from mocap_calib.core.position.engine import Theta, Windows
from mocap_calib.core.position.graph import (  # noqa: F401  (re-exported)
    KEY_G,
    KEY_GM,
    KEY_P,
    KEY_R,
    KEY_T,
    PositionGraph,
    PositionInit,
    Prior,
    build_position_graph,
    key_effect,
    theta_of,
)
from mocap_calib.core.position.noise_fit import CorrelationFit, fit_mocap_correlation
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.stages.figures import ResidualSeries, StageStats

Array = NDArray[np.float64]

IterationHook = Callable[[str, int, dict[str, Any], float], None]

@dataclass
class PositionResult:
    """Stage 3 estimates with covariances in GTSAM tangent spaces."""

    R_MI: Array
    p_MI: Array
    g_dir: Array
    g_mag: float
    delta: float
    effects: dict[str, Array]
    gyro_bias_mean: Array
    accel_bias_mean: Array
    knots: Array
    knot_sigma: Array  # (W, 6) marginal 1-sigma of each bias knot
    cov: dict[str, Array]
    unobservable: dict[str, str]
    stats: StageStats
    series: ResidualSeries
    chi2_per_dof: float
    windows: Windows
    weights: Array
    noise: NoiseModel
    cost: float  # chi^2 of the whole graph at the solution (NaN after a one-step refit)
    dof: int  # residual dimensions minus parameters
    solver: dict[str, Any]
    history: list[dict[str, Any]]
    covariances: Callable[[], PositionUncertainty] | None = field(default=None, repr=False)

    def with_covariance(self) -> PositionResult:
        """This result with its covariances (computed now when the fit left them out)."""
        if self.cov or self.covariances is None:
            return self
        unc = self.covariances()
        return replace(self, cov=unc.cov, knot_sigma=unc.knot_sigma,
                       unobservable=unobservable_blocks(unc.cov_model))


def block_value(pos: PositionResult, name: str, clock_shift: float) -> Array:
    """The parameter vector of an effect at a position-stage solution (the clock offset as
    ``t_d`` on the raw stamps, ``|g|`` as a 1-vector, the rest from the effect vectors)."""
    kind = EFFECTS[name].acts_on
    if kind == "clock":
        return np.array([pos.delta - clock_shift])
    if kind == "gravity":
        return np.array([pos.g_mag])
    return np.asarray(pos.effects[name], dtype=float)


def effect_estimate(pos: PositionResult, name: str,
                    clock_shift: float) -> tuple[object, object]:
    """An effect's value and 1-sigma in the result file's form (None if no covariance)."""
    eff = EFFECTS[name]
    value = eff.report_value(block_value(pos, name, clock_shift))
    cov = pos.cov.get(name)
    sigma = None if cov is None else eff.report_sigma(np.sqrt(np.maximum(np.diag(cov), 0.0)))
    return value, sigma


def run_position_stage(s: PreparedSession, model: Model, noise: NoiseModel, windows: Windows,
                       init: PositionInit, priors: list[Prior] | None = None,
                       robust: bool = True, max_iterations: int = 30, irls_rounds: int = 6,
                       adapt_noise: bool = True, weights: Array | None = None,
                       on_iteration: IterationHook | None = None,
                       progress: Callable[[str], None] | None = None,
                       covariance: bool = True, one_step: bool | int = False,
                       reweight: bool = False,
                       settled: Callable[[Theta, Theta], bool] | None = None) -> PositionResult:
    """Refine all parameters on the window factors.

    Args:
        s: prepared session; model: active effects; noise: noise densities.
        windows: from :func:`~mocap_calib.core.position.windows.make_windows`.
        init: starting values.
        priors: user priors (earlier calibrations), added as prior factors.
        robust: down-weight mocap outliers.
        adapt_noise: re-estimate the mocap noise level from the innovations.
        weights: fixed robust weights (W, m+1) from an earlier fit: no re-weighting, so that
            fits of different models minimise costs of the same family (model comparison).
        on_iteration: ``(stage, iteration, parameter values, cost)`` after every LM iteration.
        progress: called with a short message at every IRLS round.
        covariance: compute the covariances (without: only the estimate; ``cov`` is empty).
        one_step: Gauss-Newton steps from ``init`` instead of LM rounds (``True``: one; an
            int: that many): for refits from a nearby solution (segments, other noise
            densities), where the cost is nearly quadratic over the step. Between steps the
            mocap levels (with ``adapt_noise``) and the weights (with ``reweight``) follow the
            innovations, as between the rounds of a full run.
        reweight: with ``one_step`` and given ``weights``, update the weights between steps.
        settled: with ``one_step``, ``settled(before, after)`` true ends the steps early
            (never before the second, the first with the levels re-estimated).
    """
    t_start = time.perf_counter()
    pg = build_position_graph(s, model, noise, windows, init, priors)
    pg.problem.collect_scores = True  # cheap, and a later covariance needs them
    if weights is not None:
        pg.problem.weights = np.asarray(weights, dtype=float).copy()
        robust = False
    history = _History(pg, on_iteration)
    if one_step:
        fit = _gauss_newton_step(pg, adapt_noise, int(one_step), reweight, settled)
    else:
        fit = _solve_rounds(pg, max_iterations, irls_rounds if (robust or adapt_noise) else 1,
                            robust, adapt_noise, history, progress)
    sol, out = fit.values, pg.evals[-1]
    th = pg.theta(sol)
    blocks = [(name, d) for name, d in pg.problem.layout.blocks if name != "knot"]
    # A Gauss-Newton refit keeps the linearisation it last stepped from: its covariance is
    # that of the nearby point (no further evaluation).
    at = fit.linearized_at if one_step else sol

    def covariances() -> PositionUncertainty:
        return position_covariances(pg.graph, at, pg.block_keys, windows, th.knots,
                                    pg.problem.noise, out.scores, blocks, windows.count)

    unc = (covariances() if covariance
           else PositionUncertainty({}, np.zeros((windows.count, 6)), _mean_bias(windows, th)))
    stats, series, chi2, dof = _figures(pg, fit, out, time.perf_counter() - t_start)
    solver = {"position_batch_seconds": round(pg.batch.seconds, 3),
              "position_evaluations": pg.batch.evaluations, "windows": windows.count,
              "window_steps": windows.steps,
              "mocap_noise_variance_scale": [round(float(x), 4) for x in fit.noise_scale],
              "sandwich_over_model_sigma": unc.robust_ratio}
    if fit.correlation is not None:
        solver["mocap_noise_correlation_fit"] = [
            {k: round(v, 4) for k, v in row.items()} for row in fit.correlation.candidates]
    return PositionResult(
        R_MI=th.R_MI, p_MI=th.p_MI, g_dir=th.g_dir, g_mag=th.g_mag, delta=th.delta,
        effects=th.effects, gyro_bias_mean=unc.bias_mean[0:3], accel_bias_mean=unc.bias_mean[3:6],
        knots=th.knots, knot_sigma=unc.knot_sigma, cov=unc.cov,
        unobservable=unobservable_blocks(unc.cov_model), stats=stats, series=series,
        chi2_per_dof=chi2, windows=windows, weights=pg.problem.weights, noise=pg.problem.noise,
        # (a one-step refit's cost would cost an evaluation at the new values: not needed)
        cost=float("nan") if one_step else 2.0 * pg.graph.error(sol), dof=int(dof),
        solver=solver, history=history.records, covariances=None if covariance else covariances)


class _History:
    """Records every LM iterate (and the first evaluation, for the "before" figures)."""

    def __init__(self, pg: PositionGraph, on_iteration: IterationHook | None) -> None:
        self.pg = pg
        self.on_iteration = on_iteration
        self.records: list[dict[str, Any]] = []
        self.first_eval: Any = None

    def __call__(self, it: int, v: gtsam.Values, err: float) -> None:
        th = self.pg.theta(v)
        rec = {"iteration": len(self.records), "cost": float(err), "R_MI": th.R_MI.tolist(),
               "p_MI": th.p_MI.tolist(), "g_dir": th.g_dir.tolist(), "delta": th.delta,
               "gyro_bias": th.knots[:, 0:3].mean(axis=0).tolist(),
               "accel_bias": th.knots[:, 3:6].mean(axis=0).tolist()}
        self.records.append(rec)
        if self.first_eval is None and self.pg.evals:
            self.first_eval = self.pg.evals[-1]
        if self.on_iteration is not None:
            self.on_iteration("position", rec["iteration"], rec, float(err))


@dataclass
class _Fit:
    values: gtsam.Values
    iterations: int
    noise_scale: Array
    out0: Any  # the evaluation at the start values (unit weights): the "before" figures
    correlation: CorrelationFit | None = None
    linearized_at: gtsam.Values | None = None  # Gauss-Newton: the last linearisation point


def _gauss_newton_step(pg: PositionGraph, adapt_noise: bool = False, steps: int = 1,
                       robust: bool = False,
                       settled: Callable[[Theta, Theta], bool] | None = None) -> _Fit:
    """Gauss-Newton steps from the start values; the evaluation stays the one at the start.

    With ``adapt_noise`` the mocap noise (correlation and level) is first chosen again at the
    start values, as a full run given this noise model would; between steps the mocap levels
    (attitude and position apart) and with ``robust`` the weights follow the innovations of
    the last linearisation, as between a full run's rounds. One evaluation per step; after
    the second, ``settled(before, after)`` may end the steps early."""
    pp, batch = pg.problem, pg.batch
    pp.freeze_whitening(False)
    noise_scale = np.ones(2)
    if adapt_noise:
        old = pp.noise
        pp.noise = fit_mocap_correlation(pp, pg.theta(pg.values)).noise
        noise_scale = _variance_ratio(pp.noise, old)
        batch.invalidate()
    values = pg.values
    out0 = None
    for k in range(steps):
        at = values
        lin = pg.graph.linearize(at)
        interrupt.check()  # a signal during the evaluation only set the request
        out = pg.evals[-1]
        out0 = out if out0 is None else out0
        values = values.retract(lin.optimize())
        if k == steps - 1 or (k >= 1 and settled is not None
                              and settled(pg.theta(at), pg.theta(values))):
            break
        d_scale = 1.0
        if adapt_noise:
            s_rot, s_pos = np.clip(pp.mocap_noise_scale(out), 0.05, 400.0)
            pp.scale_mocap_noise(s_rot, s_pos)
            noise_scale *= (s_rot, s_pos)
            d_scale = float((s_rot * s_pos) ** -0.25)
        if robust:
            pp.update_weights(out.d_raw * d_scale)
        batch.invalidate()
    return _Fit(values, k + 1, noise_scale, out0, linearized_at=at)


def _solve_rounds(pg: PositionGraph, max_iterations: int, rounds: int, robust: bool,
                  adapt_noise: bool, hook: _History,
                  progress: Callable[[str], None] | None) -> _Fit:
    """Rounds of LM on a fixed cost; between rounds the mocap noise level is re-estimated from
    the innovations (it is rarely known well) and the robust weights are updated (IRLS)."""
    graph, batch, pp, evals = pg.graph, pg.batch, pg.problem, pg.evals
    iterations = 0
    sol = pg.values
    out0 = None
    noise_scale = np.ones(2)
    correlation = None
    # The mocap noise's correlation is chosen after the first solve (unless given), and checked
    # once more where the rest has settled: chosen at a white-noise solution, it depends on
    # where that landed; a choice that holds at its own solution does not.
    fit_corr = adapt_noise and not pp.noise.mocap_correlated
    recheck = fit_corr
    budget = rounds
    rnd = -1
    while True:
        rnd += 1
        if progress is not None:
            progress(f"position factors: solve {rnd + 1} ({pp.win.count} windows)")
        pp.freeze_whitening(True)
        batch.invalidate()
        sol, rep = run_lm(graph, sol, max_iterations, hook)
        last_report = rep
        if out0 is None:
            out0 = hook.first_eval
        iterations += rep.iterations
        # A full evaluation at the solution: whitening, statistics and marginals there.
        pp.freeze_whitening(False)
        batch.invalidate()
        batch.output(sol, 0)
        last_out = evals[-1]
        changed = False
        d_scale = 1.0  # how the whitened innovations shrink with the noise change below
        if rnd < budget - 1:
            if fit_corr and correlation is None:
                correlation = fit_mocap_correlation(pp, pg.theta(sol))
                old, pp.noise = pp.noise, correlation.noise
                ratio = _variance_ratio(pp.noise, old)
                noise_scale *= ratio
                d_scale = float(np.sqrt(np.prod(ratio)) ** -0.5)
                changed = True
            elif adapt_noise:
                s_rot, s_pos = pp.mocap_noise_scale(last_out)
                if max(abs(np.log(s_rot)), abs(np.log(s_pos))) > np.log(1.05):
                    s_rot, s_pos = np.clip([s_rot, s_pos], 0.05, 400.0)
                    pp.scale_mocap_noise(s_rot, s_pos)
                    noise_scale *= (s_rot, s_pos)
                    d_scale = float((s_rot * s_pos) ** -0.25)
                    changed = True
            if robust:
                # The weights follow the innovations under the new noise level (mocap noise
                # dominates them), so both updates share one round.
                w_before = pp.weights.copy()
                if pp.update_weights(last_out.d_raw * d_scale) < 0.25:
                    pp.weights = w_before  # keep the weights the solution was computed with
                else:
                    changed = True
        if not changed and recheck and correlation is not None:
            recheck = False
            again = fit_mocap_correlation(pp, pg.theta(sol))
            keep = (pp.noise.mocap_noise_corr_time, pp.noise.mocap_noise_corr_fraction)
            if (again.noise.mocap_noise_corr_time, again.noise.mocap_noise_corr_fraction) != keep:
                old, pp.noise = pp.noise, again.noise
                noise_scale *= _variance_ratio(pp.noise, old)
                correlation = again
                changed = True
                budget = max(budget, rnd + 4)  # room for the levels to settle again
        if not changed:
            break
        batch.invalidate()
    # Earlier rounds may stop early: the next round goes on from there. The last must converge.
    require_converged("position", last_report, max_iterations)
    return _Fit(sol, iterations, noise_scale, out0, correlation)


def _mean_bias(windows: Windows, th: Theta) -> Array:
    return np.kron(mean_bias_weights(windows)[None, :], np.eye(6)) @ th.knots.reshape(-1)


def _variance_ratio(new: NoiseModel, old: NoiseModel) -> Array:
    """Mocap noise variances (attitude, position) of ``new`` over ``old``."""
    return np.array([(new.mocap_rotation_sigma / old.mocap_rotation_sigma) ** 2,
                     (new.mocap_position_sigma / old.mocap_position_sigma) ** 2])


def _figures(pg: PositionGraph, fit: _Fit, out: Any,
             seconds: float) -> tuple[StageStats, ResidualSeries, float, int]:
    """Stage statistics, residual series and chi2/dof at the solution."""
    windows, layout, w_final = pg.problem.win, pg.problem.layout, pg.problem.weights
    out0 = fit.out0
    mask = windows.mask
    W = windows.count
    n_res = int(mask.sum())
    dof = 6 * n_res - 9 * W - layout.dim
    chi2 = float(out.chi2.sum()) / max(dof, 1)

    def rms(x: Array) -> list[float]:
        return np.sqrt(np.mean(x[mask] ** 2, axis=0)).tolist()

    inl = mask & (w_final > 0.5)

    def rms_in(x: Array) -> list[float]:
        return np.sqrt(np.mean(x[inl] ** 2, axis=0)).tolist()

    stats = StageStats(
        name="position", unit="m",
        rms_before=rms(out0.innovation[..., 3:6]), rms_after=rms(out.innovation[..., 3:6]),
        rms_after_inliers=rms_in(out.innovation[..., 3:6]),
        n_factors=W, n_residuals=n_res, outliers=int(np.sum(mask & (w_final < 0.5))),
        iterations=fit.iterations, seconds=seconds, chi2_per_dof=chi2,
        rms_rotation_deg=np.degrees(rms(out.innovation[..., 0:3])).tolist(),
        batch_evaluations=pg.batch.evaluations)
    series = ResidualSeries(
        t=windows.tau[mask], before=out0.innovation[..., 3:6][mask],
        after=out.innovation[..., 3:6][mask], weight=w_final[mask], unit="m",
        rotation_before=np.degrees(out0.innovation[..., 0:3][mask]),
        rotation_after=np.degrees(out.innovation[..., 0:3][mask]))
    return stats, series, chi2, dof


