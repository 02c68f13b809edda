"""The first fits of one take (one recording): its session prepared, its clocks aligned, the
IMU's faulty spans left out, stages 1-2 (attitude and velocity factors) and the position
stage's windows. Several takes each get their own; the position stage then fits them jointly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.clock.conventions import CLOCK_MOVE, base_fit_poor, check_conventions
from mocap_calib.core.clock.search import ClockSearch, search_clock
from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.imu_model import Intrinsics, correct
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.position.windows import Windows, make_windows
from mocap_calib.core.prepare.fault_spans import leave_out_imu_faults
from mocap_calib.core.prepare.session import PreparedSession, local_derivative, prepare
from mocap_calib.core.stages.attitude import AttitudeResult, run_attitude_stage
from mocap_calib.core.stages.velocity import VelocityResult, run_velocity_stage
from mocap_calib.errors import CalibrationError, InputError, Interrupted, ObservabilityError

Array = NDArray[np.float64]

ProgressFn = Callable[[str], None]
IterationFn = Callable[[str, int, dict[str, Any], float], None]


@dataclass
class FirstFits:
    """One take ready for the position stage.

    Attributes:
        s: its prepared session (faulty IMU spans left out).
        t_d0: the coarse clock offset (s, on the raw stamps); clock: the search behind it.
        att, vel: stages 1-2 at ``t_d0``.
        windows: the position stage's windows.
        notes: what preparing and fitting it left out or decided.
        session_info: the result file's ``session`` block.
    """

    s: PreparedSession
    t_d0: float
    clock: ClockSearch | None
    att: AttitudeResult
    vel: VelocityResult
    windows: Windows
    notes: list[str] = field(default_factory=list)
    session_info: dict[str, Any] = field(default_factory=dict)

    @property
    def delta0(self) -> float:
        return self.s.clock_shift + self.t_d0

    @property
    def t_mid(self) -> float:
        return 0.5 * float(self.s.u[0] + self.s.u[-1])


def first_fits(imu: ImuSamples, mocap: MocapPoses, opts: CalibrationOptions,
               effects0: dict[str, Array], on_iteration: IterationFn | None,
               say: ProgressFn) -> FirstFits:
    """Prepare one take and fit it up to the position stage's windows.

    Raises:
        InputError, ObservabilityError: as :func:`~mocap_calib.core.prepare.session.prepare`,
            the clock search and stages 1-2 do.
    """
    s = prepare(imu, mocap, noise=opts.noise)
    if s.imu_gaps is not None and (s.imu_gaps.count or s.imu_gaps.trimmed):
        say(s.imu_gaps.summary())
    notes = _session_notes(s)
    session_info = _session_info(imu, mocap, s)
    t_mid = 0.5 * (s.u[0] + s.u[-1])
    try:  # a failure here is often a convention mistake: name it if one explains the data
        s, t_d0, clock, left_out, att, vel = _first_fits(s, opts, effects0, t_mid,
                                                         on_iteration, say)
    except Interrupted:
        raise
    except CalibrationError:
        found = _explain_failure(s, opts, mocap.position_unit_m, say)
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
    v_imu = _imu_velocity(s, delta0, att.R_MI, vel.p_MI, att.gyro_bias)
    windows = make_windows(s, delta0, opts.window, opts.max_mocap_rate, v_imu)
    if windows.count < 2:
        raise ObservabilityError("fewer than 2 gap-free mocap windows overlap the IMU; "
                                 f"{s.gap_cause()}")
    if not opts.model.timed:
        notes.append(f"time_offset fixed at {t_d0:g} s (not in the model)")
    return FirstFits(s, t_d0, clock, att, vel, windows, notes, session_info)


def _corrector(model: Model, effects: dict[str, Array], t_mid: float, gyro_bias: Array,
               accel_bias: Array, which: str):
    """A ``(gyro, accel, u, b) -> (w, f)`` function with ``b`` the gyro or accel bias."""
    def fn(g: Array, a: Array, u: Array, b: Array) -> tuple[Array, Array]:
        bg, ba = (b, accel_bias) if which == "gyro" else (gyro_bias, b)
        c = correct(model, Intrinsics(bg, ba, effects, t_mid), g, a, u, sensitivities=False)
        return c.w, c.f
    return fn


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
    better = _screen_conventions(s, opts, t_d0, [] if clock is None else [
        c for c, _ in clock.candidates], att.stats.rms_after, vel.stats.rms_after,
        position_unit_m, say)
    if better is None:
        return t_d0, clock, att, vel
    clock = None if clock is None else replace(clock, time_offset=better, verified_by_fit=True)
    att, vel = _initial_stages(s, opts, s.clock_shift + better, effects0, t_mid, on_iteration,
                               say)
    return better, clock, att, vel


def _explain_failure(s: PreparedSession, opts: CalibrationOptions, position_unit_m: float,
                     say: ProgressFn) -> float | None:
    """After the clock alignment or stages 1-2 failed: raise the mistake that explains the
    failure, if one does.

    Returns:
        The clock offset at which the data as given fit, when that is unambiguous (the next
        best offset over a second away fits at least twice worse; periodic motion does not)
        and the model estimates the offset: the calibration can start there. Else None (the
        caller re-raises the original error).
    """
    say("checking the inputs' conventions (the first fits failed)")
    known = [] if opts.time_offset is None else [opts.time_offset]
    fit = check_conventions(s, known, opts.gravity, opts.max_offset, position_unit_m)
    free = opts.model.timed and opts.time_offset is None
    if fit is None or not free or fit.runner_up < 2.0 * fit.score:
        return None
    say(f"the data as given fit at clock offset {fit.t_d:.4f} s (closed-form fit)")
    return fit.t_d


def _screen_conventions(s: PreparedSession, opts: CalibrationOptions, t_d: float,
                        candidates: list[float], rms_attitude_deg: list[float],
                        rms_velocity: list[float], position_unit_m: float,
                        say: ProgressFn) -> float | None:
    """After stages 1-2: when their residuals are a large fraction of the motion, try the
    other conventions (nothing is computed when the fit is good).

    Returns:
        A better starting clock offset, when the data as given fit well at one more than
        :data:`CLOCK_MOVE` s from ``t_d`` (the coarse search picked a wrong lag; slow motion
        blurs its peak) and the model estimates the offset; else None.
    """
    rot = float(np.radians(np.sqrt(np.mean(np.square(rms_attitude_deg)))))
    vel = float(np.sqrt(np.mean(np.square(rms_velocity))))
    if not base_fit_poor(s, opts.keyframe_spacing, rot, vel):
        return None
    say("the first fits are poor: checking the inputs' conventions")
    fit = check_conventions(s, [t_d, *candidates], opts.gravity, opts.max_offset,
                            position_unit_m)
    free = opts.model.timed and opts.time_offset is None
    if fit is None or not free or abs(fit.t_d - t_d) <= CLOCK_MOVE:
        return None
    say(f"the data fit at clock offset {fit.t_d:.4f} s, not {t_d:.4f} s: starting there")
    return fit.t_d


def _stage_hook(on_iteration: IterationFn | None, stage: str):
    if on_iteration is None:
        return None
    return lambda it, v, err: on_iteration(stage, it, {}, err)


def _session_notes(s: PreparedSession) -> list[str]:
    notes: list[str] = list(s.notes)
    if s.dropped_mocap_rows:
        notes.append(f"{s.dropped_mocap_rows} mocap rows with NaN (occlusions) were dropped")
    if s.spikes_removed:
        notes.append(f"{s.spikes_removed} mocap samples far off their neighbours (at least 1 cm "
                     "or 3 deg: marker swaps or mis-solved frames) were removed")
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
        s, delta0, opts.noise, opts.keyframe_spacing,
        _corrector(model, effects0, t_mid, np.zeros(3), np.zeros(3), "gyro"),
        max_iterations=opts.max_iterations, on_iteration=_stage_hook(on_iteration, "attitude"))
    say("stage 2/3: velocity factors (accel bias, p_MI, gravity direction)")
    vel = run_velocity_stage(
        s, delta0, opts.noise, opts.keyframe_spacing, att.R_MI,
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
    if model.timed and opts.time_offset is None:
        say("aligning clocks (angular speed and specific force, all lags)")
        search = search_clock(s.u, s.gyro, s.accel, s.tau, s.R_WM, s.p_WM, s.clock_shift,
                              opts.max_offset, opts.gravity)
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
               if not model.timed else "check that both files are from one session")
        raise InputError(f"the IMU and mocap streams overlap for only {max(overlap, 0):.1f} s "
                         f"with a time offset of {t_d0:.3f} s; {fix}")
    return t_d0, search


def _disambiguate(s: PreparedSession, opts: CalibrationOptions, search: ClockSearch,
                  effects0: dict[str, Array], t_mid: float, say: ProgressFn) -> float:
    """Several lags correlate about equally well: fit stages 1-2 at each and keep the one
    whose fit is clearly better (half the chi2/dof of the next), else refuse."""
    best_z = search.peak_z
    cands = [t for t, z in search.candidates if z >= best_z - search.required_margin][:4]
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
