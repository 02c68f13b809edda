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
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.checks.conventions import explain_failure, screen_conventions
from mocap_calib.core.checks.degenerate import mark_single_axis, mark_undetermined
from mocap_calib.core.checks.verdict import judge
from mocap_calib.core.clock.search import MIN_MARGIN_Z, ClockSearch, search_clock
from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.imu_model import Intrinsics, correct
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.policy import MIN_SESSION_S
from mocap_calib.core.position.engine import make_windows
from mocap_calib.core.position.stage import (
    PositionInit,
    PositionResult,
    effect_estimate,
    run_position_stage,
)
from mocap_calib.core.prepare.imu_faults import leave_out_imu_faults
from mocap_calib.core.prepare.session import PreparedSession, local_derivative, prepare
from mocap_calib.core.result.calibration import CalibrationResult, Diagnostics
from mocap_calib.core.result.state import CalibrationTrace, ModelState
from mocap_calib.core.stages.attitude import AttitudeResult, run_attitude_stage
from mocap_calib.core.stages.figures import StageStats
from mocap_calib.core.stages.velocity import VelocityResult, run_velocity_stage
from mocap_calib.errors import CalibrationError, InputError, Interrupted, ObservabilityError

Array = NDArray[np.float64]

ProgressFn = Callable[[str], None]
IterationFn = Callable[[str, int, dict[str, Any], float], None]


def _crop(imu: ImuSamples, mocap: MocapPoses,
          opts: CalibrationOptions) -> tuple[ImuSamples, MocapPoses]:
    """``--start``/``--end`` (s from the IMU start) select IMU samples; the mocap is cut to
    match (with a margin for the clock offset) only when the raw stamps share an epoch. From
    clocks of different epochs it stays whole: the clock search finds the matching stretch."""
    if opts.start is None and opts.end is None:
        return imu, mocap
    lo = imu.t[0] + (opts.start or 0.0)
    hi = imu.t[0] + opts.end if opts.end is not None else np.inf
    if not hi > lo:
        raise InputError("--end must be after --start")
    imu_c = imu.select((imu.t >= lo) & (imu.t <= hi))
    _check_crop(imu, imu_c, opts)
    shift = (imu.time_origin_ns - mocap.time_origin_ns) * 1e-9
    tm = mocap.t - shift  # mocap times on the IMU clock (before the fine offset)
    if tm[-1] < imu.t[0] or tm[0] > imu.t[-1]:  # different epochs
        return imu_c, mocap
    margin = 1.0 if opts.time_offset is None else 1.0 + abs(opts.time_offset)
    return imu_c, mocap.select((tm >= lo - margin) & (tm <= hi + margin))


def _check_crop(imu: ImuSamples, cropped: ImuSamples, opts: CalibrationOptions) -> None:
    """--start/--end must leave a stretch of the session to calibrate: say where it is."""
    span = imu.t[-1] - imu.t[0]
    kept = cropped.t[-1] - cropped.t[0] if len(cropped) > 1 else 0.0
    if kept >= MIN_SESSION_S:
        return
    given = " ".join(f"--{k} {v:g}" for k, v in (("start", opts.start), ("end", opts.end))
                     if v is not None)
    left = ("nothing of the session is left" if len(cropped) < 2
            else f"only {kept:.1f} s of the session are left")
    raise InputError(f"{given}: {left} (the IMU log spans 0 to {span:.1f} s from its first "
                     f"sample); choose --start/--end within it, at least {MIN_SESSION_S:g} s apart")


def _corrector(model: Model, effects: dict[str, Array], t_mid: float, gyro_bias: Array,
               accel_bias: Array, which: str):
    """A ``(gyro, accel, u, b) -> (w, f)`` function with ``b`` the gyro or accel bias."""
    def fn(g: Array, a: Array, u: Array, b: Array) -> tuple[Array, Array]:
        bg, ba = (b, accel_bias) if which == "gyro" else (gyro_bias, b)
        c = correct(model, Intrinsics(bg, ba, effects, t_mid), g, a, u, sensitivities=False)
        return c.w, c.f
    return fn


def calibrate(imu: ImuSamples, mocap: MocapPoses, options: CalibrationOptions | None = None,
              progress: ProgressFn | None = None,
              on_iteration: IterationFn | None = None) -> CalibrationResult:
    """Calibrate the IMU against the mocap poses.

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
    opts = options or CalibrationOptions()
    opts.validate()
    model = opts.model
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    imu, mocap = _crop(imu, mocap, opts)
    s = prepare(imu, mocap, noise=opts.noise)
    notes = _session_notes(s)
    session_info = _session_info(imu, mocap, s)
    effects0 = {e.name: e.zero() for e in model.units if e.in_effects}
    for pr in opts.priors:
        if pr.block in effects0:
            effects0[pr.block] = np.asarray(pr.value, dtype=float)
    t_mid = 0.5 * (s.u[0] + s.u[-1])
    try:  # a failure here is often a convention mistake: name it if one explains the data
        s, t_d0, clock, left_out, att, vel = _first_fits(s, opts, effects0, t_mid,
                                                         on_iteration, say)
    except Interrupted:
        raise
    except CalibrationError:
        found = explain_failure(s, opts, mocap.position_unit_m, say)
        if found is None:
            raise
        notes.append(f"clock offset started at {found:.4f} s, where a closed-form fit of the "
                     "data is unambiguous (the clock search could not tell)")
        s, t_d0, clock, left_out, att, vel = _first_fits(
            s, replace(opts, time_offset=found), effects0, t_mid, on_iteration, say)
    notes += left_out
    t_d0, clock, att, vel = _screen(s, opts, t_d0, clock, att, vel, effects0, t_mid,
                                    mocap.position_unit_m, on_iteration, say)
    delta0 = s.clock_shift + t_d0
    interrupt.check()  # between stages: a stop a caller swallowed by mistake still stops

    say("stage 3/3: position factors (all parameters jointly)")
    v_imu = _imu_velocity(s, delta0, att.R_MI, vel.p_MI, att.gyro_bias)
    windows = make_windows(s, delta0, opts.window, opts.max_mocap_rate, v_imu)
    if windows.count < 2:
        raise ObservabilityError("fewer than 2 gap-free mocap windows overlap the IMU; "
                                 f"{s.gap_cause()}")
    init = PositionInit(att.R_MI, vel.p_MI, vel.gravity_dir, opts.gravity, delta0,
                        att.gyro_bias, vel.accel_bias, effects0)
    pos = run_position_stage(s, model, opts.noise, windows, init, opts.priors, opts.robust,
                             opts.max_iterations, adapt_noise=opts.adapt_noise,
                             on_iteration=on_iteration, progress=say)
    if not model.has("time_offset"):
        notes.append(f"time_offset fixed at {t_d0:g} s (not in the model)")
    diag = Diagnostics(
        residuals={"attitude": att.series, "velocity": vel.series, "position": pos.series},
        iterations=pos.history,
        trace=CalibrationTrace(session=s, model_state=ModelState.from_position(pos, model, t_mid),
                               noise_used=pos.noise, windows=pos.windows, weights=pos.weights,
                               clock=clock, position=pos))
    result = _package(pos, s, opts, [att.stats, vel.stats, pos.stats], notes, session_info, diag,
                      time.perf_counter() - t0)
    interrupt.check()
    axis = mark_single_axis(result, s, pos.delta)
    judge(result, s, pos, opts, clock, say, axis)
    mark_undetermined(result)
    interrupt.check()
    return result


def _first_fits(s: PreparedSession, opts: CalibrationOptions, effects0: dict[str, Array],
                t_mid: float, on_iteration: IterationFn | None, say: ProgressFn):
    """Clock alignment, the IMU's faulty spans left out, stages 1-2."""
    t_d0, clock = _align_clocks(s, opts, effects0, t_mid, say)
    s, left_out = leave_out_imu_faults(s, s.clock_shift + t_d0)
    att, vel = _initial_stages(s, opts, s.clock_shift + t_d0, effects0, t_mid, on_iteration,
                               say)
    return s, t_d0, clock, left_out, att, vel


def _screen(s: PreparedSession, opts: CalibrationOptions, t_d0: float,
            clock: ClockSearch | None, att: AttitudeResult, vel: VelocityResult,
            effects0: dict[str, Array], t_mid: float, position_unit_m: float,
            on_iteration: IterationFn | None, say: ProgressFn):
    """The convention check when stages 1-2 fit poorly; restarts them at the clock offset a
    closed-form fit finds when the search picked a wrong lag."""
    better = screen_conventions(s, opts, t_d0, [] if clock is None else [
        c for c, _ in clock.candidates], att.stats.rms_after, vel.stats.rms_after,
        position_unit_m, say)
    if better is None:
        return t_d0, clock, att, vel
    clock = None if clock is None else replace(clock, time_offset=better, verified_by_fit=True)
    att, vel = _initial_stages(s, opts, s.clock_shift + better, effects0, t_mid, on_iteration,
                               say)
    return better, clock, att, vel


def _stage_hook(on_iteration: IterationFn | None, stage: str):
    if on_iteration is None:
        return None
    return lambda it, v, err: on_iteration(stage, it, {}, err)


def _session_notes(s: PreparedSession) -> list[str]:
    notes: list[str] = list(s.notes)
    if s.dropped_mocap_rows:
        notes.append(f"{s.dropped_mocap_rows} mocap rows with NaN (occlusions) were dropped")
    if s.spikes_removed:
        notes.append(f"{s.spikes_removed} mocap samples with implausible jumps (marker swaps) "
                     "were removed")
    return notes


def _session_info(imu: ImuSamples, mocap: MocapPoses, s: PreparedSession) -> dict[str, Any]:
    return {
        "imu_samples": len(imu), "mocap_samples": len(mocap),
        "imu_rate_hz": round(s.imu_rate, 3), "mocap_rate_hz": round(s.mocap_rate, 3),
        "duration_s": round(min(imu.duration, mocap.duration), 3),
        "mocap_spikes_removed": s.spikes_removed,
        "imu_start_ns": int(imu.time_origin_ns + round(float(imu.t[0]) * 1e9)),
    }


def _initial_stages(s: PreparedSession, opts: CalibrationOptions, delta0: float,
                    effects0: dict[str, Array], t_mid: float,
                    on_iteration: IterationFn | None = None,
                    say: ProgressFn | None = None) -> tuple[AttitudeResult, VelocityResult]:
    """Stages 1 and 2 at clock offset ``delta0``."""
    model, say = opts.model, say or (lambda _m: None)
    say("stage 1/3: attitude factors (gyro bias, R_MI)")
    att = run_attitude_stage(
        s, delta0, opts.noise, opts.attitude_spacing,
        _corrector(model, effects0, t_mid, np.zeros(3), np.zeros(3), "gyro"),
        max_iterations=opts.max_iterations, on_iteration=_stage_hook(on_iteration, "attitude"))
    say("stage 2/3: velocity factors (accel bias, p_MI, gravity direction)")
    vel = run_velocity_stage(
        s, delta0, opts.noise, opts.velocity_spacing, att.R_MI,
        _corrector(model, effects0, t_mid, att.gyro_bias, np.zeros(3), "accel"), opts.gravity,
        max_iterations=opts.max_iterations, on_iteration=_stage_hook(on_iteration, "velocity"))
    return att, vel


def _align_clocks(s: PreparedSession, opts: CalibrationOptions, effects0: dict[str, Array],
                  t_mid: float, say: ProgressFn) -> tuple[float, ClockSearch | None]:
    """The starting ``t_d``: the coarse search when the model estimates it (and none is
    given), else the given value; checks that the streams then overlap.

    Raises:
        ObservabilityError: the search cannot tell which lag is right (refused, not guessed).
    """
    model = opts.model
    search = None
    if model.has("time_offset") and opts.time_offset is None:
        say("aligning clocks (angular speed and specific force, all lags)")
        search = search_clock(s.u, s.gyro, s.accel, s.tau, s.R_WM, s.p_WM, s.clock_shift,
                              opts.max_offset)
        if not search.resolved:
            chosen = _disambiguate(s, opts, search, effects0, t_mid, say)
            search = replace(search, time_offset=chosen, verified_by_fit=True)
        t_d0 = search.time_offset
    else:
        t_d0 = opts.time_offset or 0.0
    delta0 = s.clock_shift + t_d0
    overlap = min(s.u[-1] + delta0, s.tau[-1]) - max(s.u[0] + delta0, s.tau[0])
    if overlap < 10.0:
        fix = ("add time_offset to the model (--model base+time_offset) to search the offset"
               if not model.has("time_offset") else "check that both files are from one session")
        raise InputError(f"the IMU and mocap streams overlap for only {max(overlap, 0):.1f} s "
                         f"with a time offset of {t_d0:.3f} s; {fix}")
    return t_d0, search


def _disambiguate(s: PreparedSession, opts: CalibrationOptions, search: ClockSearch,
                  effects0: dict[str, Array], t_mid: float, say: ProgressFn) -> float:
    """Several lags correlate about equally well: fit stages 1-2 at each and keep the one
    whose fit is clearly better (half the chi2/dof of the next), else refuse."""
    best_z = search.peak_z
    cands = [t for t, z in search.candidates if z >= best_z - MIN_MARGIN_Z][:4]
    if best_z < 3.0 or len(cands) < 2:
        raise ObservabilityError(
            "cannot align the clocks: no lag of the two streams correlates clearly (peak "
            f"{best_z:.1f} null sigmas); check that IMU and mocap are from the same session, "
            "or give --time-offset")
    costs = []
    for t in cands:
        say(f"checking clock offset candidate {t:.4f} s")
        try:
            _, vel = _initial_stages(s, opts, s.clock_shift + t, effects0, t_mid)
            costs.append(vel.stats.chi2_per_dof)
        except Interrupted:
            raise
        except CalibrationError:
            costs.append(np.inf)
    order = np.argsort(costs)
    if np.isfinite(costs[order[0]]) and costs[order[0]] < 0.5 * costs[order[1]]:
        return float(cands[order[0]])
    listed = ", ".join(f"{t:.4g} s" for t in cands)
    raise ObservabilityError(
        f"cannot resolve the clock offset: lags {listed} fit about equally well (periodic "
        "motion?); pass --time-offset S if you know it, or --max-offset S to limit the search")


def _package(pos: PositionResult, s: PreparedSession, opts: CalibrationOptions,
             stages: list[StageStats], notes: list[str], session_info: dict[str, Any],
             diag: Diagnostics, seconds: float) -> CalibrationResult:
    """The result: values (None where unobservable), sigmas, effects, solver figures."""
    model = opts.model
    sr, sp = pos.solver["mocap_noise_variance_scale"]
    if max(abs(np.log(sr)), abs(np.log(sp))) > np.log(1.1):
        notes.append(
            f"mocap noise estimated from the residuals: {1e3 * pos.noise.mocap_position_sigma:.3g} "
            f"mm, {np.degrees(pos.noise.mocap_rotation_sigma):.3g} deg per axis (assumed "
            f"{1e3 * opts.noise.mocap_position_sigma:.3g} mm, "
            f"{np.degrees(opts.noise.mocap_rotation_sigma):.3g} deg)")
    # The sigmas are the larger of the model's and the sandwich's (see uncertainty.py), which
    # already carries residuals beyond the noise model: no chi2 scaling on top.
    if pos.chi2_per_dof > 1.2:
        notes.append(f"residuals exceed the noise model (chi2/dof = {pos.chi2_per_dof:.2f}); "
                     "the sigmas follow the residuals' own scatter (sandwich covariance)")

    def sig(name: str) -> Array | None:
        if name not in pos.cov:
            return None
        return np.sqrt(np.maximum(np.diag(pos.cov[name]), 0))

    unob = dict(pos.unobservable)

    def val(name: str, v: Array) -> Array | None:
        return None if name in unob else v

    effects: dict[str, dict[str, Any]] = {}
    for name in model.effects:
        eff = EFFECTS[name]
        if eff.acts_on == "clock":  # the clock offset has its own result key
            continue
        value, sigma = effect_estimate(pos, name, s.clock_shift)
        effects[name] = {eff.param: None if name in unob else value, "sigma": sigma}
        if eff.acts_on == "clock_rate" and name not in unob:
            effects[name]["ppm"] = 1e6 * float(value)
    t_d = pos.delta - s.clock_shift
    sig_td = sig("time_offset")
    solver = {"total_seconds": round(seconds, 3),
              "position_chi2_per_dof": round(pos.chi2_per_dof, 4), **pos.solver}
    return CalibrationResult(
        gyro_bias=val("gyro_bias", pos.gyro_bias_mean),
        accel_bias=val("accel_bias", pos.accel_bias_mean),
        rotation_wxyz=val("rotation", so3.rotmat_to_quat(pos.R_MI)),
        translation=val("translation", pos.p_MI),
        gravity_in_mocap=val("gravity", pos.g_dir),
        time_offset=None if "time_offset" in unob else float(t_d),
        sigma_gyro_bias=sig("gyro_bias"), sigma_accel_bias=sig("accel_bias"),
        sigma_rotation=sig("rotation"), sigma_translation=sig("translation"),
        sigma_gravity=sig("gravity"),
        sigma_time_offset=None if sig_td is None else float(sig_td[0]),
        gravity_magnitude=float(pos.g_mag), model=str(model), effects=effects,
        unobservable=unob, stages=stages, solver=solver,
        noise=pos.noise, notes=notes, session=session_info, diagnostics=diag)


def _imu_velocity(s: PreparedSession, delta: float, R_MI: Array, p_MI: Array,
                  gyro_bias: Array) -> Array:
    """IMU velocity at every mocap sample (local fit + lever arm): start guesses of windows."""
    half = max(2, int(round(0.05 * s.mocap_rate)))
    _, vM, valid = local_derivative(s.tau, s.p_WM, half, s.gap)
    u = np.clip(s.tau - delta, s.u[0], s.u[-1])
    w = np.stack([np.interp(u, s.u, s.gyro[:, i]) for i in range(3)], axis=1) - gyro_bias
    v = vM + np.einsum("nij,nj->ni", s.R_WM @ so3.hat(w @ R_MI.T), np.broadcast_to(p_MI, w.shape))
    v[~valid] = 0.0
    return v
