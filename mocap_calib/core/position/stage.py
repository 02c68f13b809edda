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

:class:`PositionSolver` holds the problem (takes, model, noise densities, user priors):
:meth:`~PositionSolver.solve` runs the rounds from start values, :meth:`~PositionSolver.refit`
takes Gauss-Newton steps from a nearby solution (:mod:`.settle` runs either).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.covariance import (
    CovarianceInputs,
    PositionUncertainty,
    TakeUncertainty,
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
from mocap_calib.core.position.noise import NoiseIdentification
from mocap_calib.core.position.session_mean import knot_weights
from mocap_calib.core.position.settle import (
    Fit,
    History,
    IterationHook,
    gauss_newton_steps,
    solve_rounds,
)
from mocap_calib.core.position.windows import Seed, Windows
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.stages.figures import ResidualSeries, StageStats

Array = NDArray[np.float64]
T = TypeVar("T")

#: The memo key of the solution's own evaluation (per take, a :class:`Seed`).
FINAL_EVALUATION = "final evaluation"


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
    #: the biases' covariance as the knots' mean's own (see TakeUncertainty)
    cov_knots: dict[str, Array] = field(default_factory=dict)

    @property
    def s(self) -> PreparedSession:
        return self.take.s

    @property
    def windows(self) -> Windows:
        return self.take.windows


@dataclass(frozen=True)
class PositionFigures:
    """How the stage's solve went, under the names the result file's ``solver`` section gives
    them (:meth:`to_dict`)."""

    batch_seconds: float  # the window factors' evaluations, s
    evaluations: int
    windows: int  # over every take
    window_steps: int  # mocap steps of the longest window
    rounds: int  # settling rounds and the final solve (Gauss-Newton: steps)
    rounds_capped: bool  # the settling rounds ended at their cap, the levels still moving
    mocap_noise_variance_scale: tuple[float, float]  # attitude, position: on the given levels
    #: Per block, the sandwich's sigma over the model's, per component.
    sandwich_over_model_sigma: dict[str, list[float]]

    def to_dict(self) -> dict[str, Any]:
        return {"position_batch_seconds": self.batch_seconds,
                "position_evaluations": self.evaluations,
                "windows": self.windows,
                "window_steps": self.window_steps,
                "position_rounds": self.rounds,
                "position_rounds_capped": self.rounds_capped,
                "mocap_noise_variance_scale": list(self.mocap_noise_variance_scale),
                "sandwich_over_model_sigma": self.sandwich_over_model_sigma}


class Memo:
    """Values derived from one solution by the checks after it (the correlated mocap noise
    model it prefers, ...), each computed on first use under the key its user names."""

    def __init__(self) -> None:
        self._values: dict[str, Any] = {}

    def get(self, key: str, compute: Callable[[], T]) -> T:
        if key not in self._values:
            self._values[key] = compute()
        return self._values[key]


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
    figures: PositionFigures
    history: list[dict[str, Any]]
    covariances: Callable[[], PositionUncertainty] | None = field(default=None, repr=False)
    #: The mocap noise's shape per axis (attitude x, y, z in the IMU frame, position x, y, z in
    #: the world frame), variance factors on ``noise``'s two levels (geometric mean 1 each).
    axis_scale: Array = field(default_factory=lambda: np.ones(6))
    #: The noise model the data prefer, when it was identified (used if it contradicts the
    #: given one: then ``noise`` is it).
    identification: NoiseIdentification | None = None
    #: What the checks compute from this solution once (shared with the copies ``replace``
    #: makes of it, such as :meth:`with_covariance`'s).
    memo: Memo = field(default_factory=Memo, repr=False, compare=False)

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
        """This result with its covariances (computed here when the fit left them out)."""
        if self.cov or self.covariances is None:
            return self
        unc = self.covariances()
        takes = [replace(t, cov=u.cov, knot_sigma=u.knot_sigma, cov_knots=u.cov_knots)
                 for t, u in zip(self.takes, unc.takes, strict=True)]
        return replace(self, cov={**unc.cov, **unc.takes[0].cov}, takes=takes,
                       unobservable=unobservable_blocks(unc.cov_model))


def block_value(pos: PositionResult, name: str, clock_shift: float) -> Array:
    """The parameter vector of an effect at a position-stage solution (the clock offset as
    ``t_d`` on the raw stamps, ``|g|`` as a 1-vector, the rest from the effect vectors)."""
    eff = EFFECTS[name]
    if eff.acts_on == "clock":
        return np.array([pos.delta - clock_shift])
    if eff.acts_on == "gravity":
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


@dataclass(frozen=True)
class Rounds:
    """How :meth:`PositionSolver.solve` runs.

    Attributes:
        robust: down-weight mocap outliers (Huber's kernel on the whitened innovations).
        adapt_noise: re-estimate the mocap noise levels from the innovations between rounds.
        identify_noise: and identify every level from the windows' likelihood after the first
            solve (:mod:`.noise`), used from then on where it contradicts the given noise.
        rounds: at most this many LM runs when the levels or weights move (else one).
        max_iterations: LM iterations of the first and the last run.
        near_trials: near the solution, the dampings an LM iteration tries (see
            :func:`~mocap_calib.core.gtsam_tools.run_lm`; None: as many as LM's range holds).
    """

    robust: bool = True
    adapt_noise: bool = True
    identify_noise: bool = False
    rounds: int = 6
    max_iterations: int = 30
    near_trials: int | None = None

    @classmethod
    def effect_test(cls, max_iterations: int) -> Rounds:
        """One LM run with the noise model and weights held (a refit that tests an effect),
        done near its solution (steps under 1.4 sigma) when four dampings find no lower cost:
        the rest of LM's range costs up to ten evaluations an iteration for steps its test and
        estimate do not need."""
        return cls(robust=False, adapt_noise=False, max_iterations=max_iterations,
                   near_trials=4)


@dataclass(frozen=True)
class Steps:
    """How :meth:`PositionSolver.refit` runs: Gauss-Newton steps from a nearby solution
    (segments, other noise models). Between steps the mocap levels (``adapt_noise``) and the
    robust weights (``reweight``) follow the innovations, as between the rounds of a solve;
    ``settled(before, after)`` true ends the steps early (never before the second, the first
    with the levels re-estimated)."""

    steps: int = 1
    adapt_noise: bool = False
    reweight: bool = False
    settled: Callable[[Theta, Theta], bool] | None = None


@dataclass(frozen=True)
class Weighting:
    """The mocap residuals' weighting carried over from an earlier fit.

    Attributes:
        weights: per take, robust weights (W, m+1) held fixed (no down-weighting of its own,
            so that fits of different models minimise costs of the same family); None: the
            solve weights the samples itself.
        axis_scale: the mocap noise's shape per axis to start from; None: even.
    """

    weights: list[Array] | None = None
    axis_scale: Array | None = None


@dataclass(frozen=True)
class Keep:
    """What a result keeps besides the estimate.

    Attributes:
        covariance: the covariances (without: ``cov`` is empty and
            :meth:`PositionResult.with_covariance` computes them when asked).
        window_blocks: the sandwich's blocks are the windows (else their one-second parts:
            the diagnosis' tests, calibrated with those).
        series: every take's residual series (reports; a refit needs none: 40 MB/h).
        time_mean: the biases' covariance against their mean over time (one more filter pass;
            what a reported sigma is); else the knots' mean's own (refits that compare).
    """

    covariance: bool = True
    window_blocks: bool = True
    series: bool = True
    time_mean: bool = True


class PositionSolver:
    """Stage 3 over the takes of one rig (one take for a single recording).

    Args:
        takes: every take's prepared session and windows.
        model: the active effects; noise: the noise densities (and the mocap's starting
            levels).
        priors: user priors (earlier calibrations), added as prior factors.
        on_iteration: ``(stage, iteration, parameter values, cost)`` after every LM iteration.
        progress: called with a short message as the solve advances.
    """

    def __init__(self, takes: list[Take], model: Model, noise: NoiseModel,
                 priors: list[Prior] | None = None, *,
                 on_iteration: IterationHook | None = None,
                 progress: Callable[[str], None] | None = None) -> None:
        self.takes, self.model, self.noise, self.priors = takes, model, noise, priors
        self.on_iteration, self.progress = on_iteration, progress

    def solve(self, init: PositionInit, rounds: Rounds | None = None,
              weighting: Weighting | None = None, keep: Keep | None = None) -> PositionResult:
        """Every parameter refined from ``init`` by LM rounds; the mocap levels and robust
        weights settle between them (given ``weighting.weights``: those, held fixed)."""
        rounds, weighting = rounds or Rounds(), weighting or Weighting()
        t_start = time.perf_counter()
        pg = self._graph(init, weighting)
        robust = rounds.robust and weighting.weights is None
        history = History(pg, self.on_iteration)
        keep = keep or Keep()
        n = rounds.rounds if (robust or rounds.adapt_noise or rounds.identify_noise) else 1
        fit = solve_rounds(pg, rounds.max_iterations, n, robust, rounds.adapt_noise, history,
                           self.progress, rounds.identify_noise, integrals=keep.time_mean,
                           near_trials=rounds.near_trials)
        return self._finish(pg, fit, fit.values, history.records, keep, t_start, refit=False)

    def refit(self, init: PositionInit, steps: Steps | None = None,
              weighting: Weighting | None = None, keep: Keep | None = None,
              seeds: list[Seed | None] | None = None) -> PositionResult:
        """Gauss-Newton steps from ``init``, a nearby solution. The covariance is that of the
        last linearisation point (no further evaluation), the cost NaN. ``seeds``: per take,
        an evaluation of its windows to reuse where the first step evaluates (see
        :class:`~mocap_calib.core.position.windows.Seed`)."""
        steps = steps or Steps()
        t_start = time.perf_counter()
        pg = self._graph(init, weighting or Weighting())
        for pp, seed in zip(pg.problems, seeds or [], strict=False):
            pp.use_seed(seed)
        fit = gauss_newton_steps(pg, steps.adapt_noise, steps.steps, steps.reweight,
                                 steps.settled)
        assert fit.linearized_at is not None
        return self._finish(pg, fit, fit.linearized_at, [], keep or Keep(), t_start,
                            refit=True)

    def _graph(self, init: PositionInit, weighting: Weighting) -> PositionGraph:
        pg = build_position_graph(self.takes, self.model, self.noise, init, self.priors)
        for pp in pg.problems:
            pp.collect_scores = True  # cheap, and a covariance needs them
            if weighting.axis_scale is not None:
                pp.mocap_axis_scale = np.asarray(weighting.axis_scale, dtype=float).copy()
        if weighting.weights is not None:
            pg.set_weights(weighting.weights)
        return pg

    def _finish(self, pg: PositionGraph, fit: Fit, at: gtsam.Values,
                history: list[dict[str, Any]], keep: Keep, t_start: float,
                refit: bool) -> PositionResult:
        """The result at ``fit``, with its covariances at ``at`` (computed here, or on demand
        without ``keep.covariance``)."""
        takes, outs = self.takes, pg.evals[-1]
        thetas = pg.thetas(fit.values)
        blocks = [(name, d) for name, d in pg.problem.layout.blocks if name != "knot"]

        def covariances() -> PositionUncertainty:
            # The bias's time mean: one more filter pass, with the bias integrals.
            means = pg.session_means(at) if keep.time_mean else None
            inp = CovarianceInputs(pg.shared_keys, blocks, [t.windows for t in takes],
                                   pg.knot0, [th.knots for th in thetas], means,
                                   self.model.timed,
                                   [o.scores for o in outs], keep.window_blocks,
                                   [o.extras.get("term_scores") for o in outs])
            return position_covariances(pg.graph, at, inp)

        if keep.covariance:
            unc = covariances()
        else:
            unc = PositionUncertainty({}, [TakeUncertainty(
                {}, np.zeros((t.windows.count, 6)), knot_weights(t.windows) @ th.knots)
                for t, th in zip(takes, thetas, strict=True)])
        res = _result(pg, fit, thetas, unc, time.perf_counter() - t_start, history, refit,
                      keep.series)
        if not refit:  # the solution's own evaluation, for refits of parts of it
            res.memo.get(FINAL_EVALUATION, lambda: [
                Seed(th, o, np.arange(t.windows.count), pp.noise, pp.weights.copy(),
                     pp.mocap_axis_scale.copy(), pp.motion)
                for th, o, t, pp in zip(thetas, outs, takes, pg.problems, strict=True)])
        return res if keep.covariance else replace(res, covariances=covariances, cov={})


def _result(pg: PositionGraph, fit: Fit, thetas: list[Theta], unc: PositionUncertainty,
            seconds: float, history: list[dict[str, Any]], refit: bool,
            keep_series: bool = True) -> PositionResult:
    """The stage's result from its fit and covariances."""
    takes = pg.takes
    outs = pg.evals[-1]
    stats, series, chi2, dof = _figures(pg, fit, outs, seconds, keep_series)
    figures = PositionFigures(
        round(pg.batch.seconds, 3), pg.batch.evaluations, sum(t.windows.count for t in takes),
        max(t.windows.steps for t in takes), fit.rounds, fit.capped,
        (round(float(fit.noise_scale[0]), 4), round(float(fit.noise_scale[1]), 4)),
        unc.robust_ratio)
    fits = [TakeFit(t, th.delta, th.knots, u.knot_sigma, u.bias_mean[0:3], u.bias_mean[3:6],
                    u.cov, p.weights, sr, u.cov_knots)
            for t, th, u, p, sr in zip(takes, thetas, unc.takes, pg.problems, series,
                                       strict=True)]
    th0 = thetas[0]
    return PositionResult(
        R_MI=th0.R_MI, p_MI=th0.p_MI, g_dir=th0.g_dir, g_mag=th0.g_mag, effects=th0.effects,
        takes=fits, cov={**unc.cov, **unc.takes[0].cov},
        unobservable=unobservable_blocks(unc.cov_model), stats=stats, chi2_per_dof=chi2,
        noise=pg.problem.noise,
        # (a Gauss-Newton refit's cost would cost an evaluation at the new values: not needed)
        cost=float("nan") if refit else 2.0 * pg.graph.error(fit.values), dof=int(dof),
        figures=figures, history=history,
        axis_scale=pg.problem.mocap_axis_scale.copy(),
        identification=fit.identification)


def _figures(pg: PositionGraph, fit: Fit, outs: list[Any], seconds: float,
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
