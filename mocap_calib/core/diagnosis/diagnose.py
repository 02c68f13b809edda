"""Model diagnosis: find what the calibrated model misses, name it, add it, repeat; or say
honestly that the cause is none of the effects it knows.

1. Calibrate the starting model (default: the base model, no time offset).
2. Predict what the IMU should have measured from the mocap through the calibrated model and
   compare with what it measured (:mod:`mocap_calib.core.diagnosis.predict`): residual RMS per
   sensor and axis in a low band, against the noise floor that noise alone (IMU noise, bias
   walk, the mocap noise as estimated, correlated in time) gives through the same processing.
3. For every candidate effect, refit with it added (noise model and robust weights frozen, so
   every fit minimises a cost of the same family) and test it: the noise-scaled likelihood
   ratio ``T = (chi2_M - chi2_M+e) / max(1, chi2/dof)`` and the Wald statistic of its
   parameters with the sandwich covariance (robust to a noise model that is off); the smaller
   counts, against ``chi2_k``, Bonferroni-corrected over the candidates tried.
4. The most significant candidate must also *show* in the measurement domain (lower the
   low-band residual of its sensor) and be *plausible* (its magnitude within the range a MEMS
   IMU has, :mod:`mocap_calib.core.plausible`): an implausible one is listed under
   ``implausible`` and the next candidate is considered. The first that passes is added; the
   loop repeats until none passes.
5. If the residual then still exceeds the floor, the report says so under ``unexplained``, with
   a signature that points at the cause (:mod:`mocap_calib.core.diagnosis.signature`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy import special

from mocap_calib.core import interrupt
from mocap_calib.core.clock.search import search_clock
from mocap_calib.core.diagnosis.predict import analyse_residuals
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
    combine_noise,
    combine_rms,
    evidence_row,
    homogeneity,
    shared,
    take_result,
    take_state,
)
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, CLOCK_OFFSET, EFFECTS, Model
from mocap_calib.core.model.stats import chi2_logsf
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.params import group, param
from mocap_calib.core.pipeline.calibrate import Recording, calibrate_takes
from mocap_calib.core.plausible import PlausibleLimits, effect_problem
from mocap_calib.core.position.engine import PositionProblem, Theta
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
from mocap_calib.core.result.state import ModelState
from mocap_calib.core.uncertainty.mocap_noise import fit_mocap_correlation
from mocap_calib.errors import CalibrationError, InputError, Interrupted

Array = NDArray[np.float64]

__all__ = ["DiagnoseOptions", "DiagnoseReport", "DiagnoseStep", "CandidateScore", "Residuals",
           "REPORT_KIND", "REPORT_VERSION", "diagnose", "diagnose_takes"]


def _effect_names(text: str) -> tuple[str, ...]:
    """``--candidates``: effect names joined by '+' (checked against the registry)."""
    return tuple(Model.parse(text).effects)


@dataclass
class DiagnoseOptions:
    """How to diagnose.

    Attributes:
        start_model: the starting model (default: base, no time offset).
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

    start_model: Model = param(Model(), "the model the diagnosis starts from, e.g. base or "
                               "base+time_offset", parse=Model.parse, metavar="MODEL")
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


def _log10_sf(t: float, k: int) -> float:
    """log10 P(chi2_k > t), finite far into the tail.

    Where scipy underflows (t beyond about 1400) the upper incomplete gamma's asymptotic series
    takes over: Q(a, x) = x^(a-1) e^-x / Gamma(a) * (1 + (a-1)/x + (a-1)(a-2)/x^2 + ...), with
    a = k/2 << x = t/2, so a few terms are exact to double precision. (Wilson-Hilferty, used
    before, is off by hundreds of decades there for 1 dof and ranked a 1-dof effect with
    T = 4562 below one with T = 1142.)"""
    lp = float(chi2_logsf(t, k))
    if np.isfinite(lp):
        return lp / np.log(10.0)
    a, x = 0.5 * k, 0.5 * t
    series, term = 1.0, 1.0
    for n in range(1, 8):
        term *= (a - n) / x
        series += term
    return float(((a - 1.0) * np.log(x) - x - special.gammaln(a)
                  + np.log(series)) / np.log(10.0))


def _sensor_of(effect: str) -> str:
    e = EFFECTS[effect]
    if e.sensor in ("gyro", "accel"):
        return e.sensor
    return "accel" if e.acts_on == "gravity" else "both"


def _drop(before: Residuals, after: Residuals, sensor: str) -> float:
    if sensor == "both":
        return max(_drop(before, after, "gyro"), _drop(before, after, "accel"))
    return 1.0 - after.ratio(sensor) / before.ratio(sensor)


@dataclass
class _Session:
    """What every fit of one diagnosis shares: every take's session and windows, their robust
    weights and bias-model middles (one take: a single recording)."""

    takes: list[Take]
    weights: list[Array]
    t_mids: list[float]
    opts: DiagnoseOptions
    notes: list[str] = field(default_factory=list)
    coarse_deltas: list[float] | None = None
    degraded: list[Degradation] = field(default_factory=list)

    @property
    def s(self) -> PreparedSession:
        return self.takes[0].s

    @property
    def t_mid(self) -> float:
        return self.t_mids[0]

    def alone(self, k: int) -> _Session:
        """Take ``k`` on its own (same options and weights)."""
        return _Session([self.takes[k]], [self.weights[k]], [self.t_mids[k]], self.opts)

    def dof_of(self, effect: str) -> int:
        """Parameters an effect adds: the clock offset once per take, the rest once."""
        return EFFECTS[effect].dim * (1 if shared(effect) else len(self.takes))

    def fit(self, m: Model, base: PositionResult, nz: NoiseModel,
            extra: dict[str, Array] | None = None, adapt: bool = False,
            covariance: bool = True) -> PositionResult:
        starts = [TakeStart(tf.delta, tf.gyro_bias_mean, tf.accel_bias_mean, tf.knots)
                  for tf in base.takes]
        for name, v in (extra or {}).items():
            if EFFECTS[name].acts_on == "clock":  # v: every take's offset
                for st, d in zip(starts, v, strict=True):
                    st.delta = float(d)
        init = PositionInit(base.R_MI, base.p_MI, base.g_dir, base.g_mag, starts,
                            {**base.effects, **{k: v[:1] for k, v in (extra or {}).items()}})
        return PositionSolver(self.takes, m, nz).solve(
            init, Rounds(robust=False, adapt_noise=adapt,
                         max_iterations=self.opts.calibration.max_iterations),
            Weighting(self.weights, base.axis_scale),
            Keep(covariance=covariance, window_blocks=False))

    def correlated(self, pos: PositionResult, m: Model) -> NoiseModel:
        """The mocap noise model (AR(1) and level) the windows' likelihood prefers at ``pos``:
        the tests compare likelihoods, and a white noise model would count correlated
        residuals as independent evidence (several takes: each take's, combined)."""
        out = []
        for k, (take, w, t_mid) in enumerate(zip(self.takes, self.weights, self.t_mids,
                                                 strict=True)):
            tf = pos.takes[k]
            pp = PositionProblem(take.s, m, pos.noise, take.windows, split=False)
            pp.weights = w
            pp.mocap_axis_scale = pos.axis_scale.copy()
            th = Theta(pos.R_MI, pos.p_MI, pos.g_dir, gtsam.Unit3(pos.g_dir).basis(),
                       pos.g_mag, tf.delta, dict(pos.effects), tf.knots, t_mid)
            out.append(fit_mocap_correlation(pp, th).noise)
        return combine_noise(out)

    def residuals(self, pos: PositionResult, m: Model, nz: NoiseModel) -> Residuals:
        """Low-band residuals against the floor (several takes: together; the first take's
        series kept for plots)."""
        ras = [analyse_residuals(tf.s, take_state(pos, k, m, self.t_mids[k]), nz,
                                 cutoff_hz=self.opts.cutoff_hz)
               for k, tf in enumerate(pos.takes)]
        if len(ras) == 1:
            return Residuals.of(ras[0])
        return Residuals(*combine_rms(ras), analysis=ras[0])

    def start_values(self, cand: str) -> dict[str, Array]:
        """Where a candidate's fit starts: the clock offsets from the coarse search, the rest
        from the nested model's value (zero)."""
        eff = EFFECTS[cand]
        if eff.acts_on != "clock":
            return {}
        if self.coarse_deltas is None:
            self.coarse_deltas = [
                search_clock(s.u, s.gyro, s.accel, s.tau, s.R_WM, s.p_WM,
                             s.clock_shift).time_offset + s.clock_shift
                for s in (t.s for t in self.takes)]
        return {cand: np.array(self.coarse_deltas)}

    def holds(self, c: CandidateScore, model: Model,
              fits: dict[str, tuple[PositionResult, Residuals]], current: PositionResult,
              noise: NoiseModel, threshold: float) -> str | None:
        """Several takes: refit the effect in each take alone (from the joint solution) and
        record each take's evidence in ``c.takes``; the reason when the takes' estimates
        disagree (None: it holds, or a single take)."""
        if len(self.takes) == 1:
            return None
        m = model.with_effect(c.effect)
        joint = fits[c.effect][0]
        alone, rows = [], []
        for k in range(len(self.takes)):
            one = self.alone(k)
            without = one.fit(model, take_result(current, k), noise, covariance=False)
            f = one.fit(m, take_result(joint, k), noise)
            sc = _test(one, c.effect, f, without, threshold)
            params, sig = effect_estimate(f, c.effect, one.s.clock_shift)
            rows.append(evidence_row(k, sc.log10_p, threshold, params, sig))
            alone.append(f)
        c.takes = rows
        if not shared(c.effect):
            return None
        q, dof = homogeneity(alone, c.effect)
        lp = _log10_sf(q, dof)
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
                   progress: Callable[[str], None] | None = None) -> DiagnoseReport:
    """The diagnosis of one rig from several takes: every fit is joint (shared ``T_MI``,
    gravity and effects, each take its own clock offset and biases, as ``calibrate``), and an
    effect is found only when it also holds across the takes (:mod:`.takes`); each take's own
    evidence is reported with it."""
    opts = options or DiagnoseOptions()
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    ds, model, current = _start(recordings, opts, say)
    noise = current.noise
    cur_res = ds.residuals(current, model, noise)
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
        scores, fits = _score_candidates(ds, model, current, noise, cur_res, todo, threshold,
                                         len(steps) + 1, say)
        step = DiagnoseStep(str(model), cur_res, current.cost, current.dof, scores,
                            series={"position": current.series})
        steps.append(step)
        best = _first_plausible(scores, opts.plausible, implausible, len(steps),
                                partial(ds.holds, model=model, fits=fits, current=current,
                                        noise=noise, threshold=threshold))
        if best is None:
            break
        f, res = fits[best.effect]
        step.added, step.added_params, step.added_sigma = best.effect, best.params, best.sigma
        step.residuals_after = res
        say(f"step {len(steps)}: {best.effect} explains the gap (T = {best.statistic:.1f} on "
            f"{best.dof} dof, log10 p = {best.log10_p:.1f})")
        found.append(best.effect)
        model = model.with_effect(best.effect)
        # The noise model again from the residuals left: its correlated part may have been
        # absorbing the effect just added.
        white = ds.fit(model, f, replace(noise, mocap_noise_corr_time=0.0,
                                         mocap_noise_corr_fraction=0.0), adapt=True)
        current = ds.fit(model, white, ds.correlated(white, model), adapt=True)
        if current.noise != noise:
            noise = current.noise
            cur_res = ds.residuals(current, model, noise)
        else:
            cur_res = res
    report = _finish(recordings, ds, model, current, steps, say)
    report.found, report.implausible, report.threshold_log10_p = found, implausible, threshold
    report.seconds = time.perf_counter() - t0
    return report


def _start(recordings: list[Recording], opts: DiagnoseOptions,
           say: Callable[[str], None]) -> tuple[_Session, Model, PositionResult]:
    """Fit the starting model, then refit it with frozen robust weights (so every later
    comparison uses the same cost) and its mocap noise re-estimated."""
    model = opts.start_model
    notes: list[str] = []
    # The starting fit only seeds the diagnosis: no segment or noise checks, and a model that
    # misses an effect may well look implausible (that is what the diagnosis is for).
    cal_opts = replace(opts.calibration, model=model, adapt_noise=False, segments=0,
                       sensitivity=False, accept_implausible=True, effect_tests=False)
    say(f"fitting the starting model {model}")
    try:
        start = calibrate_takes(recordings, cal_opts)
    except InputError:  # the streams may not even overlap without the offset
        if model.timed:
            raise
        model = model.with_effect(CLOCK_OFFSET.name)
        notes.append("the raw stamps do not overlap: time_offset added before the diagnosis")
        start = calibrate_takes(recordings, replace(cal_opts, model=model))
    tr = start.diagnostics.trace
    more = tr.position.takes[1:] if tr.position is not None else []
    ds = _Session([Take(tr.session, tr.windows), *(tf.take for tf in more)],
                  [tr.weights, *(tf.weights for tf in more)],
                  [float(tr.model_state.t_mid), *(tf.take.t_mid for tf in more)], opts, notes)
    # From the model state, not the public result: that holds None for what is unobservable.
    st0: ModelState = tr.model_state
    g_mag0 = float(np.linalg.norm(st0.g_W))
    init0 = PositionInit(
        st0.R_MI, st0.p_MI, st0.g_W / g_mag0, g_mag0,
        [TakeStart(st0.delta, st0.bias[:, 0:3].mean(axis=0), st0.bias[:, 3:6].mean(axis=0),
                   st0.bias),
         *(TakeStart(tf.delta, tf.gyro_bias_mean, tf.accel_bias_mean, tf.knots) for tf in more)],
        dict(st0.effects))
    # Every step first re-estimates the mocap noise with the current model (a missing effect
    # inflates it, so it is redone after each effect is added): its level, then its
    # correlation (the diagnosis models it; calibrate keeps it as a check only); the
    # candidates of the step are then fitted with it frozen.
    white = PositionSolver(ds.takes, model, tr.noise_used).solve(
        init0, Rounds(robust=False, adapt_noise=True), Weighting(ds.weights))
    current = ds.fit(model, white, ds.correlated(white, model), adapt=True)
    return ds, model, current


def _score_candidates(ds: _Session, model: Model, current: PositionResult, noise: NoiseModel,
                      cur_res: Residuals, todo: list[str], threshold: float, step: int,
                      say: Callable[[str], None]
                      ) -> tuple[list[CandidateScore], dict[str, tuple[PositionResult, Residuals]]]:
    scores: list[CandidateScore] = []
    fits: dict[str, tuple[PositionResult, Residuals]] = {}
    for cand in todo:
        interrupt.check()
        say(f"step {step}: trying {cand}")
        m = model.with_effect(cand)
        try:
            # Covariances (for the robust test) only where the likelihood ratio is significant.
            f = ds.fit(m, current, noise, ds.start_values(cand), covariance=False)
        except Interrupted:
            raise
        except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
            # A candidate that cannot be fitted (GTSAM: RuntimeError) is not the answer.
            ds.notes.append(f"step {step}: {cand} could not be fitted ({err})")
            ds.degraded.append(Degradation(f"diagnosis step {step}", f"{cand} could not be "
                                           f"fitted ({err})", "it is no candidate of the step"))
            continue
        score = _test(ds, cand, f, current, threshold)
        f = f.with_covariance() if score.log10_p < threshold else f
        # The measurement-domain check is only needed where the test is significant.
        res = ds.residuals(f, m, noise) if score.log10_p < threshold else cur_res
        fits[cand] = (f, res)
        score.residual_drop = float(_drop(cur_res, res, _sensor_of(cand)))
        score.significant = bool(score.log10_p < threshold and score.residual_drop > 0.0)
        scores.append(score)
    scores.sort(key=lambda c: c.log10_p)
    return scores, fits


def _test(ds: _Session, cand: str, f: PositionResult, current: PositionResult,
          threshold: float) -> CandidateScore:
    """The candidate's statistic: the smaller of the noise-scaled likelihood ratio and the
    robust Wald statistic of its parameters against the nested model's values (the Wald only
    where the likelihood ratio alone would pass: it can only lower the statistic)."""
    k = ds.dof_of(cand)
    d = current.cost - f.cost
    scale = max(1.0, f.cost / max(f.dof, 1))
    lr = max(d, 0.0) / scale
    if _log10_sf(lr, k) >= threshold:
        params, sig = effect_estimate(f, cand, ds.s.clock_shift)
        return CandidateScore(cand, k, float(d), float(scale), float(lr), _log10_sf(lr, k),
                              False, 0.0, params, sig, wald=float("nan"))
    f = f.with_covariance()
    shift = block_value(f, cand, 0.0) - (block_value(current, cand, 0.0)
                                         if EFFECTS[cand].acts_on in ("clock", "gravity")
                                         else 0.0)
    cov = f.cov.get(cand)
    wald = float(shift @ np.linalg.solve(cov, shift)) if cov is not None else lr
    stat = min(lr, wald)
    params, sig = effect_estimate(f, cand, ds.s.clock_shift)
    return CandidateScore(cand, k, float(d), float(scale), float(stat), _log10_sf(stat, k),
                          False, 0.0, params, sig, wald=wald)


def _first_plausible(scores: list[CandidateScore], limits: PlausibleLimits,
                     implausible: list[dict], step: int,
                     holds: Callable[[CandidateScore], str | None] = lambda _c: None
                     ) -> CandidateScore | None:
    """The most significant candidate whose magnitude is plausible and that holds across the
    takes; the others on the way are listed with the reason (never added)."""
    for c in scores:
        if not c.significant:
            continue
        problem = effect_problem(c.effect, c.params, limits)
        # Takes that disagree now may agree once the model has what is missing (their clock
        # offsets, say): such a candidate is tried again at the next step.
        disagree = holds(c) if problem is None else None
        if problem is None and disagree is None:
            return c
        c.implausible = problem or disagree
        implausible.append({"step": step, "effect": c.effect, "value": c.params,
                            "reason": c.implausible,
                            **({"takes_disagree": True} if disagree else {})})
    return None


def _finish(recordings: list[Recording], ds: _Session, model: Model,
            current: PositionResult, steps: list[DiagnoseStep],
            say: Callable[[str], None]) -> DiagnoseReport:
    """The final calibration with the model found, and the signature of any gap left (the
    first take's, with several)."""
    opts = ds.opts
    say(f"final calibration with {model}")
    final = calibrate_takes(recordings, replace(opts.calibration, model=model,
                                                accept_implausible=True))
    fx = final.diagnostics.trace
    # The noise floor is the diagnosis' noise model's (correlated mocap noise): the final
    # calibration's own is white, its level fitted to the innovations.
    if len(recordings) > 1 and fx.position is not None:
        final_res = ds.residuals(fx.position, model, current.noise)
    else:
        final_res = Residuals.of(analyse_residuals(fx.session, fx.model_state, current.noise,
                                                   cutoff_hz=opts.cutoff_hz))
    steps.append(DiagnoseStep(str(model), final_res, current.cost, current.dof, [],
                              series={"position": current.series}))
    unexplained = None
    # The final calibration (clock search, noise model chosen from the session) is what the
    # user gets; the gap it leaves, not the search's last step, decides what is unexplained.
    why = why_unexplained(final_res, current.noise, opts.unexplained_ratio,
                          opts.typical_mocap_noise)
    if why and final_res.analysis is not None:
        say("describing the residual no candidate explains")
        if fx.position is not None:  # several takes: the first one's
            pos, s_final, st = take_result(fx.position, 0), fx.session, fx.model_state
        else:
            pos = current.with_covariance()
            s_final, st = ds.s, ModelState.from_position(pos, model, ds.t_mid)
        unexplained = {"why": why, **unexplained_signature(
            s_final, st, final_res.analysis, pos, opts.unexplained_ratio)}
    return DiagnoseReport([], str(opts.start_model), str(model), steps, final, final_res, 0.0,
                          ds.notes, 0.0, [], unexplained, list(ds.degraded))
