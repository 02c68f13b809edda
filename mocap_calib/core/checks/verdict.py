"""The verdict on a finished calibration: plausible or refused, consistent, robust to the noise
models, with one documented rule for every reported sigma.

1. Plausibility (:mod:`~mocap_calib.core.checks.plausibility`): an answer no physical rig could
   have is refused (exit 4), or with ``accept_implausible`` returned marked as such.
2. Consistency (:mod:`~mocap_calib.core.uncertainty.segments`): the session's time segments
   (and its takes) calibrated on their own.
3. Sensitivity (:mod:`~mocap_calib.core.uncertainty.sensitivity`): the answer under IMU noise
   densities x3 and x1/3 and under the correlated mocap noise model the session prefers.

The rule, per parameter and component (``uncertainty`` in the result lists every term):

    sigma = max( sqrt( (c * s_stat)^2 + d_imu^2 + d_mocap^2 + d_effects^2 ),  m )

- ``s_stat``: the larger of the model-based and the sandwich sigma (windows as blocks);
- ``c``: the consistency factor, 1 unless two segments (or takes) disagree by more than 3
  combined sigmas; then the larger of their Birge ratio and max_z / 3, so that the reported
  sigma covers the disagreement the session itself shows (never a failed check with the sigmas
  it contradicted);
- ``d_imu``, ``d_mocap``: how far the answer moves under the other IMU densities and under the
  correlated mocap noise model, beyond what the reweighting explains by chance (Hausman);
- ``d_effects``: the same for the model with the effects the data show but the model lacks
  (the score tests at the solution; none shown, no term);
- ``m``: the largest plain move under any of those models: a user who assumed it would get
  that answer, and the sigma covers it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.checks.degenerate import single_axis_refusal
from mocap_calib.core.checks.plausibility import check_plausibility
from mocap_calib.core.clock.search import ClockSearch
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.position.stage import PositionResult
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.uncertainty.segments import (
    Consistency,
    segment_consistency,
    take_consistency,
)
from mocap_calib.core.uncertainty.sensitivity import (
    EFFECTS_SHOWN,
    MOCAP_AR1,
    Sensitivity,
    noise_sensitivity,
)
from mocap_calib.errors import PlausibilityError

Array = NDArray[np.float64]

#: Result field of each sigma and the sensitivity's name for it.
_SIGMAS = {"R_MI": "sigma_rotation", "p_MI": "sigma_translation", "t_d": "sigma_time_offset",
           "gyro_bias": "sigma_gyro_bias", "accel_bias": "sigma_accel_bias",
           "gravity": "sigma_gravity"}
#: A move of the answer under the correlated mocap model beyond this many sigmas is named.
MOCAP_MODEL_NOTE_SIGMA = 2.0


def judge(r: CalibrationResult, sessions: list[PreparedSession], pos: PositionResult,
          opts: CalibrationOptions, clocks: list[ClockSearch | None],
          say: Callable[[str], None], single_axis: Array | None = None) -> dict[str, float]:
    """Fill ``r``'s clock, plausibility, consistency, sensitivity and uncertainty sections and
    set its sigmas by the rule (in place). Returns the seconds the consistency and the
    sensitivity steps took.

    Args:
        single_axis: the one rotation axis of degenerate motion (marker frame), if any: an
            implausible answer is then blamed on the motion, which is named.

    Raises:
        PlausibilityError: the answer is implausible and ``opts.accept_implausible`` is off.
        ObservabilityError: the same, on motion about one axis only.
    """
    clock = clocks[0] if len(clocks) == 1 else None
    if clock is not None:
        r.clock = clock.to_dict()
        if r.time_offset is not None:
            r.clock["fine_time_offset"] = r.time_offset
    r.plausibility = check_plausibility(r, opts.plausible,
                                        None if clock is None else clock.time_offset)
    if r.plausibility["failed"]:
        reasons = "; ".join(r.plausibility["failed"])
        if not opts.accept_implausible and single_axis is not None:
            raise single_axis_refusal(single_axis, f"the fit: {reasons}")
        if not opts.accept_implausible:
            raise PlausibilityError(
                f"implausible calibration: {reasons}; check the inputs' units, conventions and "
                "clock, or pass --accept-implausible to write it marked as such")
        r.notes.append(f"IMPLAUSIBLE (accepted with --accept-implausible): {reasons}")
    cons, takes, sens = Consistency(), Consistency(), Sensitivity()
    t0 = time.perf_counter()
    if opts.segments >= 2:
        say(f"consistency: {opts.segments} segments calibrated on their own")
        cons = segment_consistency(pos, opts.model, opts.segments, opts.max_iterations)
    if len(pos.takes) > 1:
        say(f"consistency: {len(pos.takes)} takes calibrated on their own")
        takes = take_consistency(pos, opts.model, opts.max_iterations)
    t1 = time.perf_counter()
    if opts.sensitivity:
        say("sensitivity: IMU noise densities x3 and x1/3, correlated mocap noise")
        shown = tuple((r.effect_tests or {}).get("shown", ()))
        sens = noise_sensitivity(pos, opts.model, max_iterations=opts.max_iterations,
                                 priors=opts.priors, effects_shown=shown)
    t2 = time.perf_counter()
    total = _apply_rule(r, cons, takes, sens)
    r.consistency = cons.to_dict()
    if takes.segments or takes.note:
        r.consistency["takes"] = takes.to_dict()
    r.sensitivity = sens.to_dict(total)
    _notes(r, cons, takes, sens, total)
    return {"consistency": round(t1 - t0, 3), "sensitivity": round(t2 - t1, 3)}


def _apply_rule(r: CalibrationResult, cons: Consistency, takes: Consistency,
                sens: Sensitivity) -> dict[str, Array]:
    """The reported sigmas by the module's rule (in place); returns them, and lists every
    term under ``r.uncertainty``."""
    total: dict[str, Array] = {}
    r.uncertainty = {}
    imu = tuple(k for k in sens.shift if k not in (MOCAP_AR1, EFFECTS_SHOWN))
    for param, attr in _SIGMAS.items():
        v = getattr(r, attr)
        if v is None:
            continue
        stat = np.atleast_1d(np.asarray(v, dtype=float))
        c = max(cons.factor(param), takes.factor(param))
        d_imu = sens.systematic(param, imu)
        d_moc = sens.systematic(param, (MOCAP_AR1,))
        d_eff = sens.systematic(param, (EFFECTS_SHOWN,))
        move = sens.largest_move(param)
        var = (c * stat) ** 2
        for d in (d_imu, d_moc, d_eff):
            if d is not None and d.shape == stat.shape:
                var = var + d**2
        sig = np.sqrt(var)
        if move is not None and move.shape == sig.shape:
            sig = np.maximum(sig, move)
        total[param] = sig
        setattr(r, attr, float(sig[0]) if param == "t_d" else sig)
        r.uncertainty[param] = {
            "statistical": stat.tolist(), "consistency_factor": round(float(c), 3),
            "imu_noise_shift": None if d_imu is None else d_imu.tolist(),
            "mocap_model_shift": None if d_moc is None else d_moc.tolist(),
            "effects_shown_shift": None if d_eff is None else d_eff.tolist(),
            "largest_move": None if move is None else move.tolist(),
            "total": sig.tolist()}
    return total


def _notes(r: CalibrationResult, cons: Consistency, takes: Consistency, sens: Sensitivity,
           total: dict[str, Array]) -> None:
    for name, c in (("segments", cons), ("takes", takes)):
        grown = {k: c.factor(k) for k in c.max_z if c.factor(k) > 1.0}
        if grown:
            scaled = ", ".join(f"{k} x{v:.2f}" for k, v in grown.items())
            r.notes.append(f"the {len(c.segments)} {name} disagree beyond their own sigmas "
                           f"(largest pairwise z {max(c.max_z[k] for k in grown):.1f}): "
                           f"statistical sigmas grown to cover them ({scaled})")
    moved = {k: float(np.max(v / np.asarray(r.uncertainty[k]["statistical"])))
             for k, v in sens.raw.get(MOCAP_AR1, {}).items() if k in r.uncertainty}
    big = {k: v for k, v in moved.items() if v > MOCAP_MODEL_NOTE_SIGMA}
    if big:
        m = sens.mocap_model
        r.notes.append(
            f"a correlated mocap noise model (AR(1), {m.get('time_constant_s', 0):g} s, "
            f"fraction {m.get('fraction', 0):g}) moves "
            + ", ".join(f"{k} by {v:.1f}" for k, v in big.items())
            + " of its statistical sigma: the sigmas carry that move as model uncertainty")
    used = r.noise.accelerometer_noise_density
    if sens.accel_density and used and abs(np.log(sens.accel_density / used)) > np.log(2.0):
        r.notes.append(
            f"the accelerometer's noise is not the {used:.3g} m/s^2/sqrt(Hz) used: at this "
            f"solution the windows' likelihood is best at {sens.accel_density:.3g} "
            f"({sens.accel_density / used:.3g} x; in flight the rotors' vibration adds to the "
            "data sheet's); --accel-noise-from-data estimates it with the mocap's levels and "
            "uses it")
    if EFFECTS_SHOWN in sens.raw:
        r.notes.append("the sigmas carry how far the answer moves when the effects the data "
                       "show are added to the model (" + ", ".join(r.effect_tests["shown"])
                       + "): fit them with --model auto")
    if sens.shift:
        r.notes.append("sigmas include the shifts under other noise models (IMU densities x3 "
                       "and x1/3, correlated mocap noise) beyond chance and cover their moves "
                       "(the uncertainty section lists every term)")
