"""The calibration pipeline: coarse clock alignment, then three staged factor graphs.

1. Coarse time offset by cross-correlating angular speed (any offset, any epochs).
2. Attitude factors -> ``R_MI``, gyro bias.
3. Velocity factors -> accel bias, ``p_MI``, gravity direction.
4. Position factors (window likelihoods) -> every parameter jointly, with the fine time offset
   and the model's effects; marginal covariances give the 1-sigma values.

Each stage starts from the previous one's result; no user guess is needed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.checks.degenerate import (
    mark_single_axis,
    single_axis,
    single_axis_refusal,
)
from mocap_calib.core.checks.effect_scores import ALPHA, effect_scores, windows_tested
from mocap_calib.core.checks.verdict import judge
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
    Parameter,
)
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.first_fits import FirstFits, IterationFn, ProgressFn, first_fits
from mocap_calib.core.position.graph import PositionInit, Take, TakeStart
from mocap_calib.core.position.stage import (
    PositionResult,
    PositionSolver,
    Rounds,
    effect_estimate,
)
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.calibration import CalibrationResult, Diagnostics
from mocap_calib.core.result.estimate import Estimate
from mocap_calib.core.result.sections import (
    ClockSummary,
    Degradation,
    ImuGapsSummary,
    NoiseIdentification,
    SolverFigures,
    TakeResult,
    per_axis_figures,
)
from mocap_calib.core.result.state import CalibrationTrace, ModelState
from mocap_calib.core.result.verdicts import EffectTests
from mocap_calib.core.stages.figures import StageStats
from mocap_calib.errors import CalibrationError, ConvergenceError, Interrupted

Array = NDArray[np.float64]

#: Most rounds of the position stage (settling rounds and the final solve).
SETTLING_ROUNDS = 6

__all__ = ["calibrate", "calibrate_takes", "fit_takes", "conclude", "Fitted", "Recording",
           "ProgressFn", "IterationFn"]


@dataclass(frozen=True)
class Recording:
    """One take of a rig: its IMU samples and mocap poses, and what to call it in the result
    (``imu``, ``mocap``: the inputs as given)."""

    imu: ImuSamples
    mocap: MocapPoses
    imu_name: str = ""
    mocap_name: str = ""


def calibrate(imu: ImuSamples, mocap: MocapPoses, options: CalibrationOptions | None = None,
              progress: ProgressFn | None = None,
              on_iteration: IterationFn | None = None) -> CalibrationResult:
    """Calibrate the IMU against the mocap poses of one recording.

    Args:
        imu: raw IMU samples.
        mocap: marker poses ``T_WM``.
        options: see :class:`CalibrationOptions`.
        progress: called with a one-line message as the stages advance.
        on_iteration: called after every solver iteration (stage, iteration, values, cost).

    Returns:
        The calibration with 1-sigma values; ``diagnostics`` holds residual series.

    Raises:
        InputError: bad options or streams that do not overlap.
        ObservabilityError: too little motion for what the model asks.
    """
    return calibrate_takes([Recording(imu, mocap)], options, progress, on_iteration)


def calibrate_takes(recordings: list[Recording], options: CalibrationOptions | None = None,
                    progress: ProgressFn | None = None,
                    on_iteration: IterationFn | None = None,
                    first: list[FirstFits] | None = None) -> CalibrationResult:
    """Calibrate one rig from several takes (recordings) together: one ``T_MI``, one mocap
    world (gravity direction), one set of IMU effects; every take its own clock offset and
    biases (a power cycle changes both). One take is :func:`calibrate`.

    The result keeps the shared quantities under their usual keys; with several takes, their
    own (clock offset, biases) are under ``takes``, in input order. ``first``: see
    :func:`fit_takes`.
    """
    return conclude(fit_takes(recordings, options, progress, on_iteration, first), progress)


@dataclass(frozen=True)
class Fitted:
    """A calibration fitted but not yet checked (:func:`fit_takes`): ``result`` without its
    effect tests, consistency, sensitivity and plausibility; :func:`conclude` adds them.

    Attributes:
        result: the fitted values, sigmas and diagnostics.
        pos: the position stage over every take.
        fits: every take's first fits.
        opts: the options it was fitted with (validated).
        seconds: the time its steps took (s): ``clock_and_stages_1_2``, ``position_stage``.
    """

    result: CalibrationResult
    pos: PositionResult
    fits: list[FirstFits]
    opts: CalibrationOptions
    seconds: dict[str, float]


def fit_takes(recordings: list[Recording], options: CalibrationOptions | None = None,
              progress: ProgressFn | None = None,
              on_iteration: IterationFn | None = None,
              first: list[FirstFits] | None = None) -> Fitted:
    """The fitting part of :func:`calibrate_takes`: the clock, stages 1-2 and the position
    stage over every take, packaged as a result without its checks. ``first``: every take's
    clock and stages 1-2 from an earlier fit whose options gave the same ones (see
    :func:`same_first_fits`), reused instead of fitted again."""
    opts = options or CalibrationOptions()
    opts.validate()
    model = opts.model
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    effects0 = {e.name: e.zero() for e in model.units if e.in_effects}
    for pr in opts.priors:
        if pr.block in effects0:
            effects0[pr.block] = np.asarray(pr.value, dtype=float)
    fits: list[FirstFits] = [] if first is None else list(first)
    for k, rec in enumerate(recordings if first is None else []):
        if len(recordings) == 1:
            fits.append(first_fits(rec.imu, rec.mocap, opts, effects0, on_iteration, say))
            continue
        name = f"take {k + 1} ({rec.imu_name or rec.imu.source})"
        say(f"{name} of {len(recordings)}")
        try:
            fits.append(first_fits(rec.imu, rec.mocap, opts, effects0, on_iteration, say))
        except Interrupted:
            raise
        except CalibrationError as err:  # which take it was, in the one line
            raise type(err)(f"{name}: {err}") from None
    interrupt.check()  # between stages: a stop a caller swallowed by mistake still stops
    t_first = time.perf_counter()
    say("stage 3/3: position factors (all parameters jointly)")
    # The shared parameters start from the take with the most windows (its stages 1-2 saw
    # the most data); every take starts its own from its own stages.
    lead = max(range(len(fits)), key=lambda k: fits[k].windows.count)
    f0 = fits[lead]
    init = PositionInit(f0.att.R_MI, f0.vel.p_MI, f0.vel.gravity_dir, opts.gravity,
                        [TakeStart(f.delta0, f.att.gyro_bias, f.vel.accel_bias) for f in fits],
                        effects0)
    pos = _position_stage(fits, lead, model, init, opts, on_iteration, say)
    takes = [Diagnostics(
        residuals={"attitude": f.att.series, "velocity": f.vel.series,
                   "position": pos.takes[k].series},
        trace=CalibrationTrace(session=f.s,
                               model_state=ModelState.from_position(pos, model, f.t_mid, k),
                               noise_used=pos.noise, windows=pos.takes[k].windows,
                               weights=pos.takes[k].weights, clock=f.clock, position=pos))
        for k, f in enumerate(fits)]
    diag = replace(takes[0], iterations=pos.history, takes=takes if len(takes) > 1 else [])
    f = fits[0]
    # With several takes, each note says which take it is about (gaps, removed samples...).
    notes = [n if len(fits) == 1 else f"take {k + 1}: {n}"
             for k, f in enumerate(fits) for n in f.notes]
    result = _package(pos, f.s, opts, [f.att.stats, f.vel.stats, pos.stats], notes,
                      f.session_info, diag, time.perf_counter() - t0)
    if f.s.imu_gaps is not None:
        result = replace(result, imu_gaps=ImuGapsSummary.of(f.s.imu_gaps))
    if len(fits) > 1:
        result = _with_takes(result, pos, fits, recordings)
    t_pos = time.perf_counter()
    return Fitted(result, pos, fits, opts, {"clock_and_stages_1_2": round(t_first - t0, 3),
                                            "position_stage": round(t_pos - t_first, 3)})


def same_first_fits(a: CalibrationOptions, b: CalibrationOptions) -> bool:
    """Whether two option sets give the same clock search and stages 1-2: these see the
    model only through whether it has a clock offset and through the effects' starting values
    (zero, or a prior's), so options that differ in the model's other effects alone give the
    same ones (with the same prior objects, none on an effect)."""
    if a.model.timed != b.model.timed or any(pr.block in EFFECTS for pr in (*a.priors,
                                                                             *b.priors)):
        return False
    if [id(x) for x in a.priors] != [id(x) for x in b.priors]:
        return False
    return replace(a, model=Model(), priors=[]) == replace(b, model=Model(), priors=[])


def conclude(fitted: Fitted, progress: ProgressFn | None = None) -> CalibrationResult:
    """The checks of a fitted calibration (:func:`fit_takes`): the effect tests, the
    single-axis mark, consistency, sensitivity, plausibility and the sigmas by the rule."""
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    result, pos, opts, fits = fitted.result, fitted.pos, fitted.opts, fitted.fits
    if opts.effect_tests:
        result = _effect_tests(result, pos, opts, say)
    interrupt.check()
    t_eff = time.perf_counter()
    result, axis = mark_single_axis(result, fits[0].s, pos.delta)
    result, steps = judge(result, [ft.s for ft in fits], pos, opts, [ft.clock for ft in fits],
                          say, axis)
    interrupt.check()
    fit_s = sum(fitted.seconds.values())
    solver = replace(result.solver,
                     total_seconds=round(fit_s + time.perf_counter() - t0, 3))
    return replace(result, solver=solver.with_steps(last={
        **fitted.seconds, "effect_tests": round(t_eff - t0, 3), **steps}))


def _position_stage(fits: list[FirstFits], lead: int, model: Model, init: PositionInit,
                    opts: CalibrationOptions, on_iteration: IterationFn | None,
                    say: ProgressFn) -> PositionResult:
    """Stage 3 over every take; a solve that crawls along a direction the motion leaves
    undetermined (one rotation axis) is refused naming the motion, not the iteration limit."""
    try:
        solver = PositionSolver([Take(f.s, f.windows) for f in fits], model, opts.noise,
                                opts.priors, on_iteration=on_iteration, progress=say)
        return solver.solve(init, Rounds(
            robust=opts.robust, adapt_noise=opts.adapt_noise,
            identify_noise=opts.adapt_noise and opts.noise_from_data, rounds=SETTLING_ROUNDS,
            max_iterations=opts.max_iterations))
    except ConvergenceError as err:
        axis = single_axis(fits[lead].s, fits[lead].delta0)
        if axis is None:
            raise
        raise single_axis_refusal(axis, f"the position stage: {err}") from None


def _effect_tests(r: CalibrationResult, pos: PositionResult, opts: CalibrationOptions,
                  say: ProgressFn) -> CalibrationResult:
    """``r`` with the score tests of the effects the model lacks; those the data show are
    named in a note."""
    total, tested = sum(t.windows.count for t in pos.takes), windows_tested(pos)
    say("effects the model lacks: score tests at the solution"
        + (f" ({tested} of {total} windows, spread over the session)" if tested < total
           else ""))
    scores = effect_scores(pos, opts.model, opts.plausible)
    if not scores:
        return r
    shown = [s for s in scores if s.shown]
    r = replace(r, effect_tests=EffectTests(
        ALPHA, tuple(s.record() for s in scores), tuple(s.effect for s in shown), total,
        tested))
    r = r.with_degraded(*(Degradation(f"effect test {s.effect}", why,
                                      "its evidence rests on the other statistic, or on none "
                                      "(log10 p 0)")
                          for s in scores for why in s.failures))
    if not shown:
        return r
    line = ("effects the data show (not in the model): "
            + ", ".join(f"{s.effect} (log10 p {s.log10_p:.1f})" for s in shown)
            + f"; --model auto adds them, or --model {opts.model}+{shown[0].effect}")
    say(line)
    return r.with_notes(line)


def _with_takes(r: CalibrationResult, pos: PositionResult, fits: list[FirstFits],
                recordings: list[Recording]) -> CalibrationResult:
    """Several takes: each one's clock offset and biases under ``takes``; the top-level
    values of what they do not share are null."""
    def sig(c: dict[str, Array], p: Parameter) -> Array | None:
        return None if p.name not in c else np.sqrt(np.maximum(np.diag(c[p.name]), 0))

    takes = []
    for k, (tf, f, rec) in enumerate(zip(pos.takes, fits, recordings, strict=True)):
        values = {TIME_OFFSET: np.array([float(tf.delta - f.s.clock_shift)]),
                  GYRO_BIAS: tf.gyro_bias_mean, ACCEL_BIAS: tf.accel_bias_mean}
        takes.append(TakeResult(
            rec.imu_name or rec.imu.source, rec.mocap_name or rec.mocap.source,
            {p: Estimate(v, sig(tf.cov, p)) for p, v in values.items()}, f.session_info,
            None if f.s.imu_gaps is None else ImuGapsSummary.of(f.s.imu_gaps),
            None if f.clock is None else ClockSummary.of(f.clock), k + 1))
    gaps = [t.imu_gaps for t in takes if t.imu_gaps is not None]
    own = {p: Estimate() for p in (TIME_OFFSET, GYRO_BIAS, ACCEL_BIAS)}
    r = replace(r.with_estimates(own), takes=tuple(takes),
                imu_gaps=ImuGapsSummary.total(gaps) if gaps else r.imu_gaps)
    return r.with_notes(f"{len(fits)} takes calibrated together: T_marker_imu, gravity_in_mocap "
                        "and the effects are shared; each take's clock offset and biases are "
                        "listed under takes")


def _package(pos: PositionResult, s: PreparedSession, opts: CalibrationOptions,
             stages: list[StageStats], notes: list[str], session_info: dict[str, Any],
             diag: Diagnostics, seconds: float) -> CalibrationResult:
    """The result: values (None where unobservable), sigmas, effects, solver figures."""
    model = opts.model
    sr, sp = pos.figures.mocap_noise_variance_scale
    att = np.degrees(pos.noise.mocap_rotation_sigma * np.sqrt(pos.axis_scale[0:3]))
    posn = 1e3 * pos.noise.mocap_position_sigma * np.sqrt(pos.axis_scale[3:6])
    ident = _identification(pos, opts)
    if ident is not None:
        notes.append(ident.summary())
    used = ident is not None and ident.used
    if not used and max(abs(np.log(sr)), abs(np.log(sp)),
                        *np.abs(np.log(pos.axis_scale))) > np.log(1.1):
        notes.append(
            "mocap noise estimated from the residuals: "
            + ", ".join(f"{x:.3g}" for x in posn) + " mm and "
            + ", ".join(f"{x:.3g}" for x in att) + " deg per axis (assumed "
            f"{1e3 * opts.noise.mocap_position_sigma:.3g} mm, "
            f"{np.degrees(opts.noise.mocap_rotation_sigma):.3g} deg)")
    # The sigmas are the larger of the model's and the sandwich's (see uncertainty.py), which
    # already carries residuals beyond the noise model: no chi2 scaling on top.
    if pos.chi2_per_dof > 1.2:
        notes.append(f"residuals exceed the noise model (chi2/dof = {pos.chi2_per_dof:.2f}); "
                     "the sigmas follow the residuals' own scatter (sandwich covariance)")
    unob = dict(pos.unobservable)
    values = {GYRO_BIAS: pos.gyro_bias_mean, ACCEL_BIAS: pos.accel_bias_mean,
              ROTATION: ROTATION.value_of(pos.R_MI), TRANSLATION: pos.p_MI,
              GRAVITY_DIRECTION: pos.g_dir,
              TIME_OFFSET: np.array([float(pos.delta - s.clock_shift)])}
    estimates = {p: Estimate(None if p.name in unob else v,
                             None if p.name not in pos.cov
                             else np.sqrt(np.maximum(np.diag(pos.cov[p.name]), 0)))
                 for p, v in values.items()}
    effects: dict[str, dict[str, Any]] = {}
    for name in model.effects:
        eff = EFFECTS[name]
        if eff.acts_on == "clock":  # the clock offset is a base parameter (TIME_OFFSET)
            continue
        value, sigma = effect_estimate(pos, name, s.clock_shift)
        effects[name] = {eff.param: None if name in unob else value, "sigma": sigma}
        if eff.acts_on == "clock_rate" and name not in unob:
            effects[name]["ppm"] = 1e6 * float(value)
    solver = SolverFigures(round(seconds, 3), round(pos.chi2_per_dof, 4), pos.figures.to_dict(),
                           per_axis_figures(att, posn))
    result = CalibrationResult(
        estimates=estimates, gravity_magnitude=float(pos.g_mag), model=str(model),
        effects=effects, unobservable=unob, stages=tuple(stages), solver=solver,
        noise=pos.noise, noise_identification=ident, notes=tuple(notes),
        session=session_info, diagnostics=diag)
    return result.with_degraded(*_settling(pos))


def _identification(pos: PositionResult, opts: CalibrationOptions) -> NoiseIdentification | None:
    """The noise identification's section (None when the noise was held fixed)."""
    found = pos.identification
    if found is None:
        return None
    return NoiseIdentification(found.noise, opts.noise, found.contradicts, found.gain,
                               found.threshold, found.windows, found.samples)


def _settling(pos: PositionResult) -> list[Degradation]:
    """The position stage's settling rounds cut off by their cap."""
    if not pos.figures.rounds_capped:
        return []
    return [Degradation(
        "position stage", f"the rounds that settle the mocap noise levels and robust weights "
        f"reached their cap ({SETTLING_ROUNDS}) before the levels and weights stopped moving",
        "the answer and its sigmas are at the last levels and weights; the "
        "sensitivity to the noise model covers what a further round could move")]
