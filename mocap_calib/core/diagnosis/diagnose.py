"""Model diagnosis: find what the calibrated model misses, name it, add it, repeat; or say
honestly that the cause is none of the effects it knows.

1. Calibrate the starting model (default: ``calibrate``'s, base with the clock offset: what
   the default calibration lacks is named) as ``calibrate`` does: its noise model identified
   from the data, its robust weights settled.
2. Predict what the IMU should have measured from the mocap through the calibrated model and
   compare with what it measured (:mod:`mocap_calib.core.diagnosis.predict`): residual RMS per
   sensor and axis in a low band, against the noise floor that noise alone (IMU noise, bias
   walk, the mocap noise as identified, correlated in time) gives through the same processing.
3. Score every candidate effect at the current solution from one linearisation
   (:mod:`mocap_calib.core.checks.effect_scores`: the score test with the model's parameters
   re-optimised to first order, the smaller of its model-based and windows' sandwich
   statistics), Bonferroni-corrected over the candidates.
4. Only the significant candidates are refitted, strongest first, from the current solution
   with the noise model and robust weights frozen (so both fits minimise one cost): the
   refit must confirm the effect (the noise-scaled likelihood ratio ``T = (chi2_M -
   chi2_M+e) / max(1, chi2/dof)`` and the Wald statistic of its parameters with the sandwich
   covariance, the smaller of the two, beyond the same threshold), *show* in the measurement
   domain (lower the low-band residual of its sensor) and be *plausible* (its magnitude within
   the range a MEMS IMU has, :mod:`mocap_calib.core.plausible`; an implausible one is
   listed under ``implausible``). The first that passes is added and the candidates are scored
   again at the refit's solution; the loop repeats until none passes.
5. The final calibration is ``calibrate`` with the model found (the starting calibration
   itself when nothing was added). If its residual still exceeds the floor, the report says so
   under ``unexplained``, with a signature that points at the cause
   (:mod:`mocap_calib.core.diagnosis.signature`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.checks.effect_scores import effect_scores
from mocap_calib.core.clock.search import search_clock
from mocap_calib.core.diagnosis.evidence import log10_sf, residual_drop, sensor_of
from mocap_calib.core.diagnosis.predict import ResidualAnalysis, analyse_residuals
from mocap_calib.core.diagnosis.report import (
    REPORT_KIND,
    REPORT_VERSION,
    CandidateScore,
    DiagnoseReport,
    DiagnoseStep,
    Residuals,
)
from mocap_calib.core.diagnosis.signature import unexplained_signature, why_unexplained
from mocap_calib.core.diagnosis.takes import (
    combine_rms,
    evidence_row,
    homogeneity,
    shared,
    stamps_disjoint,
    take_result,
    take_state,
)
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, CLOCK_OFFSET, EFFECTS, Model
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.params import group, param
from mocap_calib.core.pipeline.calibrate import (
    Fitted,
    Recording,
    conclude,
    fit_takes,
    same_first_fits,
)
from mocap_calib.core.plausible import PlausibleLimits, effect_problem
from mocap_calib.core.position.graph import PositionInit, Take, TakeStart
from mocap_calib.core.position.stage import (
    Keep,
    PositionResult,
    PositionSolver,
    Rounds,
    Weighting,
    block_value,
    effect_estimate,
)
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.sections import Degradation
from mocap_calib.core.threads import beside
from mocap_calib.errors import CalibrationError, InputError, Interrupted

Array = NDArray[np.float64]

#: The IMU's part of a noise model (densities, random walks, the accelerometer's axis shape).
IMU_NOISE = ("gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
             "accelerometer_random_walk", "accelerometer_axis_scale")

__all__ = ["DiagnoseOptions", "DiagnoseReport", "DiagnoseStep", "CandidateScore", "Residuals",
           "REPORT_KIND", "REPORT_VERSION", "diagnose", "diagnose_takes"]


def _effect_names(text: str) -> tuple[str, ...]:
    """``--candidates``: effect names joined by '+' (checked against the registry)."""
    return tuple(Model.parse(text).effects)


@dataclass
class DiagnoseOptions:
    """How to diagnose.

    Attributes:
        start_model: the starting model (default: ``calibrate``'s, base+time_offset).
        candidates: effects to try.
        alpha: family-wise false-alarm rate per step (Bonferroni over the candidates).
        max_steps: most effects to add.
        calibration: options of the underlying calibrations (noise, gravity, windows...).
        cutoff_hz: band of the measurement-domain comparison.
        plausible: the magnitudes an effect may have (beyond: listed as implausible).
        unexplained_ratio: a residual over floor ratio above which, with nothing left to
            add, the gap is reported as unexplained.
        typical_mocap_noise: per-sample mocap noise (m, rad) beyond which the noise the
            residuals imply is not the mocap's: a slow model error the correlated noise model
            absorbs (it raises the floor too, so the ratio alone would not show it).
    """

    start_model: Model = param(CalibrationOptions().model, "the model the diagnosis starts from "
                               "(default: calibrate's), e.g. base", parse=Model.parse,
                               metavar="MODEL")
    candidates: tuple[str, ...] = param(
        CANONICAL_EFFECTS, "effects to try, joined by '+' (default: every canonical effect)",
        parse=_effect_names, metavar="EFFECTS", show_default=False)
    alpha: float = param(0.01, "false-alarm rate per step (Bonferroni-corrected over the "
                         "candidates)", lo=0.0, lo_open=True, hi=0.5, hi_open=True)
    max_steps: int = param(4, "most effects to add", lo=1, hi=10)
    calibration: CalibrationOptions = group(CalibrationOptions, "Calibration")
    cutoff_hz: float = 2.0
    plausible: PlausibleLimits = field(default_factory=PlausibleLimits)
    unexplained_ratio: float = 1.5
    typical_mocap_noise: tuple[float, float] = (1.5e-3, float(np.radians(0.2)))


@dataclass
class _Session:
    """What every fit of one diagnosis shares: every take's session and windows, their robust
    weights and bias-model middles (one take: a single recording)."""

    takes: list[Take]
    weights: list[Array]
    t_mids: list[float]
    opts: DiagnoseOptions
    notes: list[str] = field(default_factory=list)
    degraded: list[Degradation] = field(default_factory=list)
    coarse_deltas: list[float] | None = None
    #: Every take's analysis at the start: its noise floor serves every refit (one noise
    #: model throughout the search).
    floors: list[ResidualAnalysis] | None = None

    @property
    def s(self) -> PreparedSession:
        return self.takes[0].s

    def dof_of(self, effect: str) -> int:
        """Parameters an effect adds: the clock offset once per take, the rest once."""
        return EFFECTS[effect].dim * (1 if shared(effect) else len(self.takes))

    def fit(self, m: Model, base: PositionResult, nz: NoiseModel,
            extra: dict[str, Array] | None = None, covariance: bool = True) -> PositionResult:
        """``m`` fitted from the solution ``base`` (an added effect from its nested value, or
        from ``extra``: every take's clock offset), with the noise model ``nz`` and the robust
        weights frozen."""
        starts = [TakeStart(tf.delta, tf.gyro_bias_mean, tf.accel_bias_mean, tf.knots)
                  for tf in base.takes]
        for name, v in (extra or {}).items():
            if EFFECTS[name].acts_on == "clock":
                for st, d in zip(starts, v, strict=True):
                    st.delta = float(d)
        init = PositionInit(base.R_MI, base.p_MI, base.g_dir, base.g_mag, starts,
                            dict(base.effects))
        solver = PositionSolver(self.takes, m, nz, self.opts.calibration.priors)
        rounds = Rounds.effect_test(self.opts.calibration.max_iterations)
        return solver.solve(init, rounds, Weighting(self.weights, base.axis_scale),
                            Keep(covariance, window_blocks=False, time_mean=False))

    def floor_noise(self, identified: NoiseModel) -> NoiseModel:
        """The noise model of the measurement-domain floor: the mocap's as identified (levels
        and correlation), the IMU's as given. An identified IMU density takes up what the
        model misses (a missing accelerometer lag passes for accelerometer noise 15 times
        its density), and the floor is what that gap is measured against."""
        given = self.opts.calibration.noise
        return replace(identified, **{k: getattr(given, k) for k in IMU_NOISE})

    def residuals(self, pos: PositionResult, m: Model, nz: NoiseModel,
                  same_floor: bool = False) -> Residuals:
        """Low-band residuals against the floor (several takes: together; the first take's
        series kept for plots). ``same_floor``: the start's floor (a refit under its noise
        model), else one of their own."""
        floors = self.floors if same_floor and self.floors else [None] * len(pos.takes)
        ras = [analyse_residuals(tf.s, take_state(pos, k, m, self.t_mids[k]), nz,
                                 cutoff_hz=self.opts.cutoff_hz, floor_of=fl)
               for k, (tf, fl) in enumerate(zip(pos.takes, floors, strict=True))]
        if self.floors is None:
            self.floors = ras
        if len(ras) == 1:
            return Residuals.of(ras[0])
        return Residuals(*combine_rms(ras), analysis=ras[0])

    def start_values(self, cand: str) -> dict[str, Array]:
        """Where a candidate's refit starts when not at its nested value: the clock offsets
        from the coarse search (a model without the offset holds it at zero)."""
        if EFFECTS[cand].acts_on != "clock":
            return {}
        if self.coarse_deltas is None:
            self.coarse_deltas = [
                search_clock(s.u, s.gyro, s.accel, s.tau, s.R_WM, s.p_WM,
                             s.clock_shift).time_offset + s.clock_shift
                for s in (t.s for t in self.takes)]
        return {cand: np.array(self.coarse_deltas)}

    def scores(self, pos: PositionResult, model: Model, todo: list[str],
               step: int) -> list[CandidateScore]:
        """Every candidate's score test at ``pos``, in order of evidence."""
        tests = effect_scores(pos, model, self.opts.plausible, tuple(todo), self.opts.alpha,
                              sequential=False, parts=True)
        for t in tests:
            for why in t.failures:
                self.degraded.append(Degradation(f"diagnosis step {step}", f"{t.effect}: {why}",
                                                 "its evidence rests on the other statistic"))
        # The significant ones in the order they are refitted: by the model-based evidence,
        # which keeps growing with an effect's size where the windows' spread (the weaker,
        # which decides significance) levels off.
        tests.sort(key=lambda t: (not t.significant, t.model_log10_p if t.significant
                                  else t.log10_p))
        return [CandidateScore(t.effect, t.dof, float("nan"), float("nan"), t.statistic,
                               t.log10_p, t.significant, float("nan"), t.estimate)
                for t in tests]

    def holds(self, c: CandidateScore, model: Model, current: PositionResult,
              threshold: float, every_take: bool) -> str | None:
        """Several takes: each take's own score test of the effect at the joint solution
        (its evidence and one-step estimate in ``c.takes``); the reason when the takes'
        estimates disagree, or (``every_take``) when a take alone does not show it (None: it
        holds, or a single take)."""
        if len(self.takes) == 1:
            return None
        tests = [effect_scores(take_result(current, k), model, self.opts.plausible,
                               (c.effect,), 10.0**threshold, sequential=False, parts=True)[0]
                 for k in range(len(self.takes))]
        eff = EFFECTS[c.effect]
        c.takes = [evidence_row(k, t.log10_p, threshold, t.estimate, eff.report_sigma(
            np.sqrt(np.maximum(np.diag(t.step_cov), 0.0))))
            for k, t in enumerate(tests)]
        if every_take:
            alone = [r["take"] for r in c.takes if not r["evidence"]]
            if alone:
                return (f"take {', '.join(map(str, alone))} alone does not show {c.effect}: "
                        "it does not hold in every take")
        if not shared(c.effect):
            return None
        q, dof = homogeneity([t.step for t in tests], [t.step_cov for t in tests])
        lp = log10_sf(q, dof)
        if lp < np.log10(self.opts.alpha):
            return (f"the takes disagree on {c.effect} (chi2 {q:.1f} on {dof} dof, log10 p "
                    f"{lp:.1f}): it does not hold across the takes")
        return None


def diagnose(imu: ImuSamples, mocap: MocapPoses, options: DiagnoseOptions | None = None,
             progress: Callable[[str], None] | None = None) -> DiagnoseReport:
    """Run the diagnosis loop (see the module docstring) on one recording.

    Args:
        imu: raw IMU samples; mocap: marker poses.
        options: see :class:`DiagnoseOptions`.
        progress: called with one-line messages.
    """
    return diagnose_takes([Recording(imu, mocap)], options, progress)


def diagnose_takes(recordings: list[Recording], options: DiagnoseOptions | None = None,
                   progress: Callable[[str], None] | None = None,
                   every_take: bool = False) -> DiagnoseReport:
    """The diagnosis of one rig from several takes: every fit is joint (shared ``T_MI``,
    gravity and effects, each take its own clock offset and biases, as ``calibrate``), and an
    effect is found only when it also holds across the takes (:mod:`.takes`; with
    ``every_take``, only when each take's own data show it); each take's own evidence is
    reported with it."""
    opts = options or DiagnoseOptions()
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    ds, model, start = _start(recordings, opts, say)
    current = start.pos
    cur_res = ds.residuals(current, model, ds.floor_noise(current.noise))
    start_res = cur_res
    found: list[str] = []
    implausible: list[dict] = []
    steps: list[DiagnoseStep] = []
    threshold = 0.0
    for _ in range(opts.max_steps):
        todo = [c for c in opts.candidates
                if not model.has(c) and c not in {x["effect"] for x in implausible
                                                  if not x.get("takes_disagree")}]
        if not todo:
            break
        threshold = float(np.log10(opts.alpha / len(todo)))
        say(f"step {len(steps) + 1}: score tests of {len(todo)} candidates")
        scores = ds.scores(current, model, todo, len(steps) + 1)
        step = DiagnoseStep(str(model), cur_res, current.cost, current.dof, scores,
                            series={"position": current.series})
        steps.append(step)
        hit = _confirm(ds, scores, model, current, cur_res, threshold, implausible,
                       len(steps), say,
                       partial(ds.holds, model=model, current=current, threshold=threshold,
                               every_take=every_take))
        if hit is None:
            break
        best, current, cur_res = hit
        step.added, step.added_params, step.added_sigma = best.effect, best.params, best.sigma
        step.residuals_after = cur_res
        say(f"step {len(steps)}: {best.effect} explains the gap (score log10 p = "
            f"{best.log10_p:.1f}; refit T = {best.confirm_statistic:.1f} on {best.dof} dof)")
        found.append(best.effect)
        model = model.with_effect(best.effect)
    report = _finish(recordings, ds, model, start, start_res, current, steps, say)
    report.found, report.implausible, report.threshold_log10_p = found, implausible, threshold
    report.seconds = time.perf_counter() - t0
    return report


def _start(recordings: list[Recording], opts: DiagnoseOptions,
           say: Callable[[str], None]) -> tuple[_Session, Model, Fitted]:
    """Fit the starting model as ``calibrate`` does (its noise model and robust weights; its
    checks only when it is the final model, :func:`_finish`); every later fit keeps its noise
    model and weights, so that every comparison uses the same cost. Accepts an implausible
    answer: a model that misses an effect may well look implausible (that is what the
    diagnosis is for)."""
    model = opts.start_model
    notes: list[str] = []
    why = "the raw stamps do not overlap: time_offset added before the diagnosis"
    if not model.timed and stamps_disjoint(recordings, opts.calibration.time_offset or 0.0):
        model = model.with_effect(CLOCK_OFFSET.name)
        notes.append(why)
    cal_opts = replace(opts.calibration, model=model, accept_implausible=True)
    say(f"fitting the starting model {model}")
    try:
        start = fit_takes(recordings, cal_opts)
    except InputError:  # the streams may not even overlap without the offset
        if model.timed:
            raise
        model = model.with_effect(CLOCK_OFFSET.name)
        notes.append(why)
        start = fit_takes(recordings, replace(cal_opts, model=model))
    tr = start.result.diagnostics.trace
    pos = tr.position
    assert pos is not None
    ds = _Session([tf.take for tf in pos.takes], [tf.weights for tf in pos.takes],
                  [float(tr.model_state.t_mid), *(tf.take.t_mid for tf in pos.takes[1:])],
                  opts, notes)
    return ds, model, start


def _confirm(ds: _Session, scores: list[CandidateScore], model: Model,
             current: PositionResult, cur_res: Residuals, threshold: float,
             implausible: list[dict], step: int, say: Callable[[str], None],
             holds: Callable[[CandidateScore], str | None] = lambda _c: None
             ) -> tuple[CandidateScore, PositionResult, Residuals] | None:
    """The strongest candidate whose refit confirms it, lowers the residual of its sensor, is
    plausible and holds across the takes: it, its refit and residuals (None: no such one).
    Only candidates the score test finds significant are refitted, in the order of their
    scores; a significant clock offset is refitted with the first and the two are taken in
    the order of their refits' evidence (a clock offset a model holds at zero can be far from
    it, where the first-order score undervalues it)."""
    order = [c for c in scores if c.significant]
    fits: dict[str, PositionResult | None] = {}
    clock = next((c for c in order if EFFECTS[c.effect].acts_on == "clock"), None)
    if clock is not None and order[0] is not clock:
        pair = [order[0], clock]
        for c in pair:
            fits[c.effect] = _refit(ds, c, model, current, threshold, step, say)
        pair.sort(key=lambda c: c.confirm_log10_p if fits[c.effect] is not None else 0.0)
        order = pair + [c for c in order if c not in pair]
    for c in order:
        f = fits[c.effect] if c.effect in fits else _refit(ds, c, model, current, threshold,
                                                           step, say)
        if f is None or not c.significant:
            continue
        m = model.with_effect(c.effect)
        res = ds.residuals(f, m, ds.floor_noise(current.noise), same_floor=True)
        c.residual_drop = float(residual_drop(cur_res, res, sensor_of(c.effect)))
        if c.residual_drop <= 0.0:
            c.significant = False
            c.refuted = "its refit does not lower the low-band residual of its sensor"
            continue
        problem = effect_problem(c.effect, c.params, ds.opts.plausible)
        # Takes that disagree now may agree once the model has what is missing (their clock
        # offsets, say): such a candidate is tried again at the next step.
        disagree = holds(c) if problem is None else None
        if problem is None and disagree is None:
            return c, f, res
        c.implausible = problem or disagree
        implausible.append({"step": step, "effect": c.effect, "value": c.params,
                            "reason": c.implausible,
                            **({"takes_disagree": True} if disagree else {})})
    return None


def _refit(ds: _Session, c: CandidateScore, model: Model, current: PositionResult,
           threshold: float, step: int, say: Callable[[str], None]) -> PositionResult | None:
    """The model with ``c`` refitted from ``current`` and tested (:func:`_refit_test`); None
    when it cannot be fitted (recorded as a degradation)."""
    interrupt.check()
    say(f"step {step}: refitting {c.effect}")
    try:
        extra = ds.start_values(c.effect)
        f = ds.fit(model.with_effect(c.effect), current, current.noise, extra,
                   covariance=False)
    except Interrupted:
        raise
    except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
        # A candidate that cannot be fitted (GTSAM: RuntimeError) is not the answer.
        ds.notes.append(f"step {step}: {c.effect} could not be fitted ({err})")
        ds.degraded.append(Degradation(f"diagnosis step {step}", f"{c.effect} could not "
                                       f"be fitted ({err})", "it is no candidate of the step"))
        c.significant = False
        return None
    return _refit_test(ds, c, f, current, threshold, nested_start=not extra)


def _refit_test(ds: _Session, c: CandidateScore, f: PositionResult, current: PositionResult,
                threshold: float, nested_start: bool) -> PositionResult:
    """The refit's confirmation of a candidate, recorded in ``c``: the smaller of the
    noise-scaled likelihood ratio and the robust Wald statistic of its parameters against the
    nested values (the Wald only where the likelihood ratio alone would pass: it can only
    lower the statistic). Both costs are the refit's own, at its start and at its end, when
    it starts at the nested model's solution (``nested_start``: one whitening of the windows,
    frozen at the start); else the current solution's and the refit's.
    Returns the refit, with its covariance when confirmed."""
    k = c.dof
    if nested_start:
        nested, ext = (2.0 * float(f.history[i]["cost"]) for i in (0, -1))
    else:
        nested, ext = current.cost, f.cost
    d = nested - ext
    scale = max(1.0, ext / max(f.dof, 1))
    lr = max(d, 0.0) / scale
    c.delta_chi2, c.scale, c.confirm_statistic = float(d), float(scale), float(lr)
    c.confirm_log10_p = log10_sf(lr, k)
    if c.confirm_log10_p < threshold:
        f = f.with_covariance()
        shift = block_value(f, c.effect, 0.0) - (block_value(current, c.effect, 0.0)
                                                 if EFFECTS[c.effect].acts_on in ("clock",
                                                                                  "gravity")
                                                 else 0.0)
        cov = f.cov.get(c.effect)
        c.wald = float(shift @ np.linalg.solve(cov, shift)) if cov is not None else lr
        c.confirm_statistic = min(lr, c.wald)
        c.confirm_log10_p = log10_sf(c.confirm_statistic, k)
    c.params, c.sigma = effect_estimate(f, c.effect, ds.s.clock_shift)
    if c.confirm_log10_p >= threshold:
        c.significant = False
        c.refuted = (f"its refit does not confirm it (T = {c.confirm_statistic:.1f} on {k} dof, "
                     f"log10 p {c.confirm_log10_p:.1f})")
    return f


def _finish(recordings: list[Recording], ds: _Session, model: Model,
            start: Fitted, start_res: Residuals, current: PositionResult,
            steps: list[DiagnoseStep], say: Callable[[str], None]) -> DiagnoseReport:
    """The final calibration with the model found (the starting one when nothing was added:
    its fit, checked as ``calibrate`` checks it), and the signature of any gap left (the first
    take's, with several)."""
    opts = ds.opts
    nothing_added = str(model) == start.result.model
    if nothing_added:
        final, final_res = conclude(start), start_res
    else:
        say(f"final calibration with {model}")
        # The starting fit's clock and stages 1-2 when the model found gives the same ones.
        final_opts = replace(opts.calibration, model=model, accept_implausible=True)
        fitted = fit_takes(recordings, final_opts, first=start.fits if same_first_fits(
            start.opts, final_opts) else None)
        # Its residuals (under its own noise model's floor) run beside its checks.
        final_res, final = beside(partial(ds.residuals, fitted.pos, model, ds.floor_noise(
            fitted.pos.noise)), partial(conclude, fitted))
    fx = final.diagnostics.trace
    pos = fx.position
    assert pos is not None
    steps.append(DiagnoseStep(str(model), final_res, current.cost, current.dof, [],
                              series={"position": current.series}))
    unexplained = None
    # The final calibration (clock search, noise model identified from the session) is what
    # the user gets; the gap it leaves, not the search's last step, decides what is
    # unexplained.
    why = why_unexplained(final_res, pos.noise, opts.unexplained_ratio,
                          opts.typical_mocap_noise)
    if why and final_res.analysis is not None:
        say("describing the residual no candidate explains")
        unexplained = {"why": why, **unexplained_signature(
            fx.session, fx.model_state, final_res.analysis,
            take_result(pos, 0).with_covariance(), opts.unexplained_ratio)}
    return DiagnoseReport([], str(opts.start_model), str(model), steps, final, final_res, 0.0,
                          ds.notes, 0.0, [], unexplained, list(ds.degraded))
