"""The verdict on a finished calibration: plausible or refused, consistent, robust to the noise
models, with one documented rule for every reported sigma.

0. Priors (:mod:`~mocap_calib.core.checks.priors`): each prior against what the session's data
   say without it; one they contradict is refused (exit 2), or kept and named.
1. Consistency (:mod:`~mocap_calib.core.uncertainty.segments`): the session's time segments
   (and its takes) calibrated on their own.
2. Sensitivity (:mod:`~mocap_calib.core.uncertainty.sensitivity`): the answer under IMU noise
   densities x3 and x1/3 and under the correlated mocap noise model the session prefers.
3. The sigmas by the rule below; a parameter whose sigma is beyond use is reported
   undetermined (:func:`~mocap_calib.core.checks.degenerate.mark_undetermined`).
4. Plausibility (:mod:`~mocap_calib.core.checks.plausibility`) of what is determined: an answer
   no physical rig could have is refused (exit 4), or with ``accept_implausible`` returned
   marked as such.

The rule, per parameter and component (``uncertainty`` in the result lists every term):

    sigma = max( sqrt( (c * s_stat)^2 + d_imu^2 + d_mocap^2 + d_effects^2 ),  m )

- ``s_stat``: the larger of the model-based and the sandwich sigma (windows as blocks);
- ``c``: the consistency factor, 1 unless two segments (or takes) disagree by more than 3
  combined sigmas; then the larger of their Birge ratio and max_z / 3, so that the reported
  sigma covers the disagreement the session itself shows (never a failed check with the sigmas
  it contradicted);
- ``d_imu``, ``d_mocap``: how far the answer moves under the other IMU densities and under the
  correlated mocap noise model, beyond what the reweighting explains by chance (Hausman),
  counted only when the move is significant (beyond 2 chance sigmas): a chance move is no
  systematic, and its positive part would pad every sigma of a correct model;
- ``d_effects``: the same for the model with the effects the data show but the model lacks
  (the score tests at the solution; none shown, no term);
- ``m``: the largest plain move under any of those models that moved beyond chance: a user
  who assumed it would get that answer, and the sigma covers it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.checks.degenerate import mark_undetermined, single_axis_refusal
from mocap_calib.core.checks.plausibility import check_plausibility
from mocap_calib.core.checks.priors import check_priors
from mocap_calib.core.checks.reports import (
    consistency_degraded,
    consistency_report,
    sensitivity_degraded,
    sensitivity_report,
)
from mocap_calib.core.clock.search import ClockSearch
from mocap_calib.core.model.parameters import Parameter
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.position.stage import PositionResult
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.calibration import UNCERTAINTY_ORDER, CalibrationResult
from mocap_calib.core.result.estimate import Estimate, SigmaTerms
from mocap_calib.core.result.sections import ClockSummary
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

#: A move of the answer under the correlated mocap model beyond this many sigmas is named.
MOCAP_MODEL_NOTE_SIGMA = 2.0


def judge(r: CalibrationResult, sessions: list[PreparedSession], pos: PositionResult,
          opts: CalibrationOptions, clocks: list[ClockSearch | None],
          say: Callable[[str], None], single_axis: Array | None = None
          ) -> tuple[CalibrationResult, dict[str, float]]:
    """``r`` with its clock, priors, plausibility, consistency, sensitivity and uncertainty
    sections and its sigmas set by the rule; and the seconds the consistency and the
    sensitivity steps took.

    Args:
        single_axis: the one rotation axis of degenerate motion (marker frame), if any: an
            implausible answer is then blamed on the motion, which is named.

    Raises:
        InputError: a prior conflicts with the session's data and
            ``opts.trust_prior`` is off (:mod:`~mocap_calib.core.checks.priors`).
        PlausibilityError: the answer is implausible and ``opts.accept_implausible`` is off.
        ObservabilityError: the same, on motion about one axis only; or the motion determines
            none of R_MI, p_MI and the clock offset.
    """
    clock = clocks[0] if len(clocks) == 1 else None
    if clock is not None:
        r = replace(r, clock=ClockSummary.of(clock, r.time_offset))
    # The priors first: one the session's data contradict is the input to blame.
    r = check_priors(r, pos, opts, say)
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
        shown = () if r.effect_tests is None else r.effect_tests.shown
        sens = noise_sensitivity(pos, opts.model, max_iterations=opts.max_iterations,
                                 priors=opts.priors, effects_shown=shown,
                                 limits=opts.plausible)
    t2 = time.perf_counter()
    # What the session cannot determine is reported as such before anything is judged
    # plausible: never a verdict on a number the result says it does not know.
    r = plausibility_gate(mark_undetermined(_apply_rule(r, cons, takes, sens)), opts, clock,
                   single_axis)
    total = {p: e.terms.total for p, e in r.estimates.items() if e.terms is not None}
    r = replace(r, consistency=consistency_report(cons, takes),
                sensitivity=sensitivity_report(sens, total))
    r = r.with_notes(*_notes(r, cons, takes, sens))
    r = r.with_degraded(*consistency_degraded(cons, "segment", opts.segments >= 2),
                        *consistency_degraded(takes, "take", len(pos.takes) > 1),
                        *sensitivity_degraded(sens))
    return r, {"consistency": round(t1 - t0, 3), "sensitivity": round(t2 - t1, 3)}


def plausibility_gate(r: CalibrationResult, opts: CalibrationOptions, clock: ClockSearch | None,
               single_axis: Array | None) -> CalibrationResult:
    """``r`` with its plausibility section (and a note when accepted as implausible).

    Raises:
        PlausibilityError: the answer is implausible and ``opts.accept_implausible`` is off.
        ObservabilityError: the same, on motion about one axis only.
    """
    plaus = check_plausibility(r, opts.plausible, None if clock is None else clock.time_offset)
    r = replace(r, plausibility=plaus)
    if not plaus.failed:
        return r
    reasons = "; ".join(plaus.failed)
    if not opts.accept_implausible and single_axis is not None:
        raise single_axis_refusal(single_axis, f"the fit: {reasons}")
    if not opts.accept_implausible:
        raise PlausibilityError(
            f"implausible calibration: {reasons}; check the inputs' units, conventions and "
            "clock, or pass --accept-implausible to write it marked as such")
    return r.with_notes(f"IMPLAUSIBLE (accepted with --accept-implausible): {reasons}")


def _apply_rule(r: CalibrationResult, cons: Consistency, takes: Consistency,
                sens: Sensitivity) -> CalibrationResult:
    """``r`` with the reported sigmas by the module's rule, each with its terms; with several
    takes, each take's own clock offset and biases by the same rule (the alternatives' shifts
    of that take's values)."""
    judged: dict[Parameter, Estimate] = {}
    for p in UNCERTAINTY_ORDER:
        e = r.estimate(p)
        if e.sigma is not None:
            judged[p] = _judged(e, p, max(cons.factor(p), takes.factor(p)), sens)
    own = []
    for k, t in enumerate(r.takes):
        sk = sens.of_take(k)
        own.append(replace(t, estimates={
            p: e if e.sigma is None else _judged(e, p, max(cons.factor(p), takes.factor(p)), sk)
            for p, e in t.estimates.items()}))
    return replace(r.with_estimates(judged), takes=tuple(own))


def _judged(e: Estimate, p: Parameter, c: float, sens: Sensitivity) -> Estimate:
    """One estimate with its sigma by the rule and the rule's terms."""
    stat = np.atleast_1d(np.asarray(e.sigma, dtype=float))
    imu = tuple(k for k in sens.shift if k not in (MOCAP_AR1, EFFECTS_SHOWN))
    d_imu = sens.systematic(p, imu)
    d_moc = sens.systematic(p, (MOCAP_AR1,))
    d_eff = sens.systematic(p, (EFFECTS_SHOWN,))
    move = sens.largest_move(p)
    var = (c * stat) ** 2
    for d in (d_imu, d_moc, d_eff):
        if d is not None and d.shape == stat.shape:
            var = var + d**2
    sig = np.sqrt(var)
    if move is not None and move.shape == sig.shape:
        sig = np.maximum(sig, move)
    terms = SigmaTerms(stat, round(float(c), 3), d_imu, d_moc, d_eff, move, sig)
    return replace(e, sigma=sig, terms=terms)


def _notes(r: CalibrationResult, cons: Consistency, takes: Consistency,
           sens: Sensitivity) -> list[str]:
    """What the checks found that a reader should know, one line each."""
    out = []
    for name, c in (("segments", cons), ("takes", takes)):
        grown = {p: c.factor(p) for p in c.max_z if c.factor(p) > 1.0}
        if grown:
            scaled = ", ".join(f"{p.symbol} x{v:.2f}" for p, v in grown.items())
            out.append(f"the {len(c.segments)} {name} disagree beyond their own sigmas "
                       f"(largest pairwise z {max(c.max_z[p] for p in grown):.1f}): "
                       f"statistical sigmas grown to cover them ({scaled})")
    stat = {p: e.terms.statistical for p, e in r.estimates.items() if e.terms is not None}
    moved = {p: float(np.max(v / stat[p])) for p, v in sens.raw.get(MOCAP_AR1, {}).items()
             if p in stat}
    big = {p: v for p, v in moved.items() if v > MOCAP_MODEL_NOTE_SIGMA}
    if big:
        m = sens.mocap_model
        out.append(
            f"a correlated mocap noise model (AR(1), {m.get('time_constant_s', 0):g} s, "
            f"fraction {m.get('fraction', 0):g}) moves "
            + ", ".join(f"{p.symbol} by {v:.1f}" for p, v in big.items())
            + " of its statistical sigma: the sigmas carry that move as model uncertainty")
    if EFFECTS_SHOWN in sens.raw and r.effect_tests is not None:
        out.append("the sigmas carry how far the answer moves when the effects the data "
                   "show are added to the model (" + ", ".join(r.effect_tests.shown)
                   + "): fit them with --model auto")
    if sens.implausible:
        out.append("the effects the data show are not added to the sigmas as model "
                   f"uncertainty: with them the fit is not physical ({sens.implausible}); a "
                   "misfit of the noise model can pass for an effect")
    if sens.shift:
        out.append("sigmas include the shifts under other noise models (IMU densities x3 "
                   "and x1/3 of those used, correlated mocap noise) beyond chance and cover "
                   "their moves (the uncertainty section lists every term)")
    return out
