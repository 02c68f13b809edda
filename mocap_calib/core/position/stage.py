"""Stage 3, position factors: refine every parameter jointly on a GTSAM factor graph.

Variables: ``R_MI`` (Rot3), ``p_MI`` (Point3), the gravity direction (Unit3), ``|g|`` when the
model estimates it, one vector per IMU-side effect (all shared by the takes), and per take its
clock offset and one bias knot (gyro + accel, Vector6) at the start of every window. Factors:
one window factor per window (:mod:`mocap_calib.core.position.engine`, evaluated together), a
random-walk between-factor for consecutive knots of a take, weak range priors that keep the
system well posed (a parameter whose uncertainty they dominate is reported as unobservable),
and user priors.

The point estimate does not depend on a noise model the session cannot verify: the mocap noise
is white, its level (attitude and position) estimated from the innovations, and mocap outliers
are down-weighted per sample by Huber's kernel on the whitened innovation (convex: one fixed
point wherever the weights start). Levels and weights settle in short LM runs on a fixed cost;
the last run goes to convergence. The correlated-noise model is a check on the answer
(:mod:`mocap_calib.core.uncertainty.sensitivity`), not part of it.
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
from mocap_calib.core.graph import PREDICTED_TOL, require_converged, run_lm
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.covariance import (
    CovarianceInputs,
    PositionUncertainty,
    TakeUncertainty,
    mean_bias_weights,
    position_covariances,
    unobservable_blocks,
)
from mocap_calib.core.position.engine import Theta
from mocap_calib.core.position.graph import (
    PositionGraph,
    PositionInit,
    Prior,
    Take,
    build_position_graph,
)
from mocap_calib.core.position.noise import NoiseIdentification, identify_noise
from mocap_calib.core.position.settle import (
    evaluate_at,
    innovations_near,
    settle,
)
from mocap_calib.core.position.windows import Windows
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.stages.figures import ResidualSeries, StageStats

Array = NDArray[np.float64]

IterationHook = Callable[[str, int, dict[str, Any], float], None]

#: LM iterations of a round that settles the levels and weights (the last round converges).
SETTLING_ITERATIONS = 4
#: Rounds end when the cost moves by less than this fraction and the levels by < 5 %.
COST_SETTLED = 1e-3


@dataclass
class TakeFit:
    """One take's own estimates (``delta``: mocap minus IMU time on the take's relative clocks;
    the knots: its bias at each window start)."""

    take: Take
    delta: float
    knots: Array
    knot_sigma: Array
    gyro_bias_mean: Array
    accel_bias_mean: Array
    cov: dict[str, Array]
    weights: Array
    series: ResidualSeries

    @property
    def s(self) -> PreparedSession:
        return self.take.s

    @property
    def windows(self) -> Windows:
        return self.take.windows


@dataclass
class PositionResult:
    """Stage 3 estimates with covariances in GTSAM tangent spaces. The shared parameters are
    fields; every take's own are in ``takes``. ``cov`` holds the shared blocks' covariances and
    the first take's own (``time_offset``, ``gyro_bias``, ``accel_bias``), so that a
    single-take caller reads everything there; the properties below are the first take's."""

    R_MI: Array
    p_MI: Array
    g_dir: Array
    g_mag: float
    effects: dict[str, Array]
    takes: list[TakeFit]
    cov: dict[str, Array]
    unobservable: dict[str, str]
    stats: StageStats
    chi2_per_dof: float
    noise: NoiseModel
    cost: float  # chi^2 of the whole graph at the solution (NaN after a Gauss-Newton refit)
    dof: int  # residual dimensions minus parameters
    solver: dict[str, Any]
    history: list[dict[str, Any]]
    covariances: Callable[[], PositionUncertainty] | None = field(default=None, repr=False)
    #: The mocap noise's shape per axis (attitude x, y, z in the IMU frame, position x, y, z in
    #: the world frame), variance factors on ``noise``'s two levels (geometric mean 1 each).
    axis_scale: Array = field(default_factory=lambda: np.ones(6))
    #: The noise model the data prefer, when it was identified (used if it contradicts the
    #: given one: then ``noise`` is it).
    identification: NoiseIdentification | None = None

    @property
    def delta(self) -> float:
        return self.takes[0].delta

    @property
    def knots(self) -> Array:
        return self.takes[0].knots

    @property
    def knot_sigma(self) -> Array:
        return self.takes[0].knot_sigma

    @property
    def gyro_bias_mean(self) -> Array:
        return self.takes[0].gyro_bias_mean

    @property
    def accel_bias_mean(self) -> Array:
        return self.takes[0].accel_bias_mean

    @property
    def windows(self) -> Windows:
        return self.takes[0].windows

    @property
    def weights(self) -> Array:
        return self.takes[0].weights

    @property
    def series(self) -> ResidualSeries:
        return self.takes[0].series

    def with_covariance(self) -> PositionResult:
        """This result with its covariances (computed now when the fit left them out)."""
        if self.cov or self.covariances is None:
            return self
        unc = self.covariances()
        takes = [replace(t, cov=u.cov, knot_sigma=u.knot_sigma)
                 for t, u in zip(self.takes, unc.takes, strict=True)]
        return replace(self, cov={**unc.cov, **unc.takes[0].cov}, takes=takes,
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


def run_position_stage(takes: list[Take], model: Model, noise: NoiseModel,
                       init: PositionInit, priors: list[Prior] | None = None,
                       robust: bool = True, max_iterations: int = 30, irls_rounds: int = 6,
                       adapt_noise: bool = True, weights: list[Array] | None = None,
                       identify_noise: bool = False,
                       on_iteration: IterationHook | None = None,
                       progress: Callable[[str], None] | None = None,
                       covariance: bool = True, one_step: bool | int = False,
                       window_blocks: bool = True, axis_scale: Array | None = None,
                       reweight: bool = False,
                       settled: Callable[[Theta, Theta], bool] | None = None,
                       series: bool = True) -> PositionResult:
    """Refine all parameters on the window factors of every take.

    Args:
        takes: every take's prepared session and windows (one for a single recording).
        model: active effects; noise: noise densities (and the mocap's starting levels).
        init: starting values.
        priors: user priors (earlier calibrations), added as prior factors.
        robust: down-weight mocap outliers.
        adapt_noise: re-estimate the mocap noise levels from the innovations;
            identify_noise: and identify every level from the windows' likelihood after the
            first solve (:mod:`.noise`), used from then on where it contradicts ``noise``.
        weights: per take, fixed robust weights (W, m+1) from an earlier fit: no re-weighting,
            so that fits of different models minimise costs of the same family.
        on_iteration: ``(stage, iteration, parameter values, cost)`` after every LM iteration.
        progress: called with a short message as the stage advances.
        covariance: compute the covariances (without: only the estimate; ``cov`` is empty).
        window_blocks: the sandwich's blocks are the windows (else their one-second parts:
            the diagnosis' tests, calibrated with those).
        axis_scale: the mocap noise's shape per axis to start from (a refit's: its fit's).
        one_step: Gauss-Newton steps from ``init`` instead of LM rounds (``True``: one; an
            int: that many): for refits from a nearby solution (segments, other noise
            models). Between steps the mocap levels (with ``adapt_noise``) and the weights
            (with ``reweight``) follow the innovations, as between the rounds of a full run.
        reweight: with ``one_step`` and given ``weights``, update the weights between steps.
        settled: with ``one_step``, ``settled(before, after)`` true ends the steps early
            (never before the second, the first with the levels re-estimated).
        series: keep every take's residual series (for reports; a refit: none, 40 MB/h).
    """
    t_start = time.perf_counter()
    pg = build_position_graph(takes, model, noise, init, priors)
    for pp in pg.problems:
        pp.collect_scores = True  # cheap, and a covariance needs them
        if axis_scale is not None:
            pp.mocap_axis_scale = np.asarray(axis_scale, dtype=float).copy()
    if weights is not None:
        pg.set_weights(weights)
        robust = False
    history = _History(pg, on_iteration)
    if one_step:
        fit = _gauss_newton_steps(pg, adapt_noise, int(one_step), reweight, settled)
    else:
        fit = _solve_rounds(pg, max_iterations,
                            irls_rounds if (robust or adapt_noise or identify_noise) else 1,
                            robust, adapt_noise, history, progress, identify_noise)
    outs = pg.evals[-1]
    thetas = pg.thetas(fit.values)
    # A Gauss-Newton refit keeps the linearisation it last stepped from: its covariance is
    # that of the nearby point (no further evaluation).
    at = fit.linearized_at if one_step else fit.values
    blocks = [(name, d) for name, d in pg.problem.layout.blocks if name != "knot"]

    def covariances() -> PositionUncertainty:
        inp = CovarianceInputs(pg.shared_keys, blocks, [t.windows for t in takes], pg.knot0,
                               [th.knots for th in thetas], model.timed,
                               [o.scores for o in outs], window_blocks)
        return position_covariances(pg.graph, at, inp, pg.problem.noise)

    if covariance:
        unc = covariances()
    else:
        unc = PositionUncertainty({}, [TakeUncertainty(
            {}, np.zeros((t.windows.count, 6)), _mean_bias(t.windows, th))
            for t, th in zip(takes, thetas, strict=True)])
    res = _result(pg, fit, thetas, unc, time.perf_counter() - t_start, history, one_step,
                  series)
    return res if covariance else replace(res, covariances=covariances, cov={})


def _result(pg: PositionGraph, fit: _Fit, thetas: list[Theta], unc: PositionUncertainty,
            seconds: float, history: _History, one_step: bool | int,
            keep_series: bool = True) -> PositionResult:
    """The stage's result from its fit and covariances."""
    takes = pg.takes
    outs = pg.evals[-1]
    stats, series, chi2, dof = _figures(pg, fit, outs, seconds, keep_series)
    solver = {"position_batch_seconds": round(pg.batch.seconds, 3),
              "position_evaluations": pg.batch.evaluations,
              "windows": sum(t.windows.count for t in takes),
              "window_steps": max(t.windows.steps for t in takes),
              "position_rounds": fit.rounds,
              "position_rounds_capped": fit.capped,
              "mocap_noise_variance_scale": [round(float(x), 4) for x in fit.noise_scale],
              "sandwich_over_model_sigma": unc.robust_ratio}
    fits = [TakeFit(t, th.delta, th.knots, u.knot_sigma, u.bias_mean[0:3], u.bias_mean[3:6],
                    u.cov, p.weights, sr)
            for t, th, u, p, sr in zip(takes, thetas, unc.takes, pg.problems, series,
                                       strict=True)]
    th0 = thetas[0]
    return PositionResult(
        R_MI=th0.R_MI, p_MI=th0.p_MI, g_dir=th0.g_dir, g_mag=th0.g_mag, effects=th0.effects,
        takes=fits, cov={**unc.cov, **unc.takes[0].cov},
        unobservable=unobservable_blocks(unc.cov_model), stats=stats, chi2_per_dof=chi2,
        noise=pg.problem.noise,
        # (a Gauss-Newton refit's cost would cost an evaluation at the new values: not needed)
        cost=float("nan") if one_step else 2.0 * pg.graph.error(fit.values), dof=int(dof),
        solver=solver, history=history.records,
        axis_scale=pg.problem.mocap_axis_scale.copy(),
        identification=getattr(pg, "identification", None))


class _History:
    """Records every LM iterate (and the first evaluation's innovations, for the "before"
    figures: only those, not the whole evaluation, are kept for the stage)."""

    def __init__(self, pg: PositionGraph, on_iteration: IterationHook | None) -> None:
        self.pg = pg
        self.on_iteration = on_iteration
        self.records: list[dict[str, Any]] = []
        self.first_innovations: list[Array] | None = None

    def __call__(self, it: int, v: gtsam.Values, err: float) -> None:
        th = self.pg.theta(v)
        rec = {"iteration": len(self.records), "cost": float(err), "R_MI": th.R_MI.tolist(),
               "p_MI": th.p_MI.tolist(), "g_dir": th.g_dir.tolist(), "delta": th.delta,
               "gyro_bias": th.knots[:, 0:3].mean(axis=0).tolist(),
               "accel_bias": th.knots[:, 3:6].mean(axis=0).tolist()}
        self.records.append(rec)
        if self.first_innovations is None and self.pg.evals:
            self.first_innovations = [o.innovation for o in self.pg.evals[-1]]
        if self.on_iteration is not None:
            self.on_iteration("position", rec["iteration"], rec, float(err))


@dataclass
class _Fit:
    values: gtsam.Values
    iterations: int
    noise_scale: Array
    innovations0: list[Array] | None  # per take, the innovations at the start values
    rounds: int = 1
    linearized_at: gtsam.Values | None = None  # Gauss-Newton: the last linearisation point
    capped: bool = False  # the settling rounds ended at their cap, the levels still moving


def _gauss_newton_steps(pg: PositionGraph, adapt_noise: bool = False, steps: int = 1,
                        robust: bool = False,
                        settled: Callable[[Theta, Theta], bool] | None = None) -> _Fit:
    """Gauss-Newton steps from the start values; between steps the mocap levels (with
    ``adapt_noise``) and the weights (with ``robust``) follow the innovations of the last
    linearisation, as between a full run's rounds. One evaluation per step; after the second,
    ``settled(before, after)`` may end the steps early. The noise model's kind (white or
    correlated) stays as given."""
    pg.for_each("freeze_whitening", False)
    noise_scale = np.ones(2)
    values = pg.values
    inn0: list[Array] | None = None
    k = 0
    at = values
    for k in range(steps):
        at = values
        lin = pg.graph.linearize(at)
        interrupt.check()  # a signal during the evaluation only set the request
        outs = pg.evals[-1]
        inn0 = [o.innovation for o in outs] if inn0 is None else inn0
        values = values.retract(lin.optimize())
        if k == steps - 1 or (k >= 1 and settled is not None
                              and settled(pg.theta(at), pg.theta(values))):
            break
        settle(pg, outs, adapt_noise, robust, noise_scale)
        del outs  # not alive while the next step evaluates
        pg.batch.invalidate()
    return _Fit(values, k + 1, noise_scale, inn0, k + 1, linearized_at=at)


def _solve_rounds(pg: PositionGraph, max_iterations: int, rounds: int, robust: bool,
                  adapt_noise: bool, hook: _History,
                  progress: Callable[[str], None] | None, identify_noise: bool = False) -> _Fit:
    """Rounds of LM on a fixed cost (whitening frozen); between rounds the mocap noise levels
    are re-estimated from the innovations and the robust weights updated. The first run goes
    to convergence from the start values; the settling rounds after it are short; once nothing
    changes (or the cost moves by less than :data:`COST_SETTLED`) one LM run goes to
    convergence."""
    graph, batch = pg.graph, pg.batch
    iterations, sol = 0, pg.values
    inn0: list[Array] | None = None
    noise_scale = np.ones(2)
    prev_cost = None
    final = settled = rounds <= 1
    given = pg.problem.noise
    ident = None
    pg.identification = None
    rnd = 0
    while True:
        rnd += 1
        if progress is not None:
            n = sum(p.win.count for p in pg.problems)
            progress(f"position factors: {'final solve' if final else 'settling'} round {rnd} "
                     f"({n} windows)")
        pg.for_each("freeze_whitening", True)
        batch.invalidate()
        # The first run converges (from stages 1-2, unit weights); later ones only settle the
        # levels and weights, until the last.
        limit = max_iterations if (final or rnd == 1) else SETTLING_ITERATIONS
        sol, rep = run_lm(graph, sol, limit, hook, predicted_tol=PREDICTED_TOL)
        inn0 = hook.first_innovations if inn0 is None else inn0
        iterations += rep.iterations
        if final:
            outs = evaluate_at(pg, sol)
            break
        outs = innovations_near(pg, sol, float(rep.final_error))
        changed, moved = settle(pg, outs, adapt_noise and ident is None, robust, noise_scale)
        if identify_noise and pg.identification is None:
            # Once, after the first solve: the levels the data prefer there, used from then
            # on when they contradict the given ones (a second identification at the final
            # solution changed no answer by a tenth of a sigma on simulated flights).
            pg.identification = identify(pg, sol, given)
            if pg.identification.contradicts:
                ident = pg.identification
                moved_a = _noise_move(pg.problem.noise, ident.noise)
                for pp in pg.problems:
                    pp.noise = ident.noise
                changed, moved = changed or moved_a > np.log(1.05), max(moved, moved_a)
        cost = float(rep.final_error)
        small = prev_cost is not None and abs(prev_cost - cost) < COST_SETTLED * abs(cost)
        prev_cost = cost
        settled = (not changed) or (small and moved < np.log(1.05))
        final = settled or rnd >= rounds - 1
        del outs  # not alive while the next round evaluates (60 min: 37 MB)
        batch.invalidate()
    require_converged("position", rep, max_iterations)
    return _Fit(sol, iterations, noise_scale, inn0, rnd, capped=not settled)


def identify(pg: PositionGraph, values: gtsam.Values,
             given: NoiseModel) -> NoiseIdentification:
    """The noise model the windows' likelihood prefers at ``values`` (every take)."""
    problems = [(pp, pg.theta(values, k)) for k, pp in enumerate(pg.problems)]
    return identify_noise(problems, pg.problem.noise, given)


def _noise_move(a: NoiseModel, b: NoiseModel) -> float:
    """The largest relative change of a level between two noise models (log of the ratio)."""
    keys = ("accelerometer_noise_density", "gyroscope_noise_density", "mocap_position_sigma",
            "mocap_rotation_sigma")
    return max(abs(float(np.log(getattr(b, k) / getattr(a, k)))) for k in keys)


def _mean_bias(windows: Windows, th: Theta) -> Array:
    return np.kron(mean_bias_weights(windows)[None, :], np.eye(6)) @ th.knots.reshape(-1)


def _figures(pg: PositionGraph, fit: _Fit, outs: list[Any], seconds: float,
             keep_series: bool = True) -> tuple[StageStats, list[ResidualSeries], float, int]:
    """Stage statistics over every take, each take's residual series (empty without
    ``keep_series``), chi2/dof."""
    layout = pg.problem.layout
    inn0 = fit.innovations0 if fit.innovations0 is not None else [o.innovation for o in outs]
    masks = [p.win.mask for p in pg.problems]
    wts = [p.weights for p in pg.problems]
    n_res = int(sum(m.sum() for m in masks))
    W = sum(p.win.count for p in pg.problems)
    dof = 6 * n_res - 9 * W - layout.dim
    chi2 = float(sum(o.chi2.sum() for o in outs)) / max(dof, 1)

    def rms(parts: list[Array], keep: list[NDArray[np.bool_]]) -> list[float]:
        x = np.concatenate([p[k] for p, k in zip(parts, keep, strict=True)])
        return np.sqrt(np.mean(x**2, axis=0)).tolist()

    inl = [m & (w > 0.5) for m, w in zip(masks, wts, strict=True)]
    pos_after = [o.innovation[..., 3:6] for o in outs]
    stats = StageStats(
        name="position", unit="m",
        rms_before=rms([x[..., 3:6] for x in inn0], masks),
        rms_after=rms(pos_after, masks), rms_after_inliers=rms(pos_after, inl),
        n_factors=W, n_residuals=n_res,
        outliers=int(sum(int(np.sum(m & (w < 0.5))) for m, w in zip(masks, wts, strict=True))),
        iterations=fit.iterations, seconds=seconds, chi2_per_dof=chi2,
        rms_rotation_deg=np.degrees(rms([o.innovation[..., 0:3] for o in outs], masks)).tolist(),
        batch_evaluations=pg.batch.evaluations)
    if not keep_series:
        masks = [np.zeros_like(m) for m in masks]
    series = [ResidualSeries(
        t=p.win.tau[m], before=b[..., 3:6][m], after=a.innovation[..., 3:6][m],
        weight=p.weights[m], unit="m",
        rotation_before=np.degrees(b[..., 0:3][m]),
        rotation_after=np.degrees(a.innovation[..., 0:3][m]))
        for p, m, b, a in zip(pg.problems, masks, inn0, outs, strict=True)]
    return stats, series, chi2, dof
