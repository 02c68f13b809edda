"""The verdict on a finished calibration: plausible or refused, consistent, robust to the noise
densities, with sigmas raised where the session's own segments show they must be.

1. Plausibility (:mod:`~mocap_calib.core.checks.plausibility`): an answer no physical rig could
   have is refused (exit 4), or with ``accept_implausible`` returned marked as such.
2. Consistency (:mod:`~mocap_calib.core.uncertainty.consistency`): the session's segments
   calibrated on their own. Where they scatter significantly more than their sigmas say (chi2
   beyond its 95 %
   point), the full session's sigmas are multiplied by the Birge ratio ``sqrt(chi2/dof)``: the
   reported sigmas are the ones that make the segments' agreement honest.
3. Sensitivity: how far the answer moves under IMU noise densities x3 and x1/3, in the sigmas
   reported.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.checks.degenerate import single_axis_refusal
from mocap_calib.core.checks.plausibility import check_plausibility
from mocap_calib.core.position.stage import PositionResult
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.uncertainty.consistency import (
    Consistency,
    Sensitivity,
    noise_sensitivity,
    segment_consistency,
)
from mocap_calib.errors import PlausibilityError

Array = NDArray[np.float64]

if TYPE_CHECKING:
    from collections.abc import Callable

    from mocap_calib.core.clock.search import ClockSearch
    from mocap_calib.core.options import CalibrationOptions


def judge(r: CalibrationResult, s: PreparedSession, pos: PositionResult,
          opts: CalibrationOptions, clock: ClockSearch | None,
          say: Callable[[str], None], single_axis: Array | None = None) -> None:
    """Fill ``r``'s clock, plausibility, consistency and sensitivity sections (in place).

    Args:
        single_axis: the one rotation axis of degenerate motion (marker frame), if any: an
            implausible answer is then blamed on the motion, which is named.

    Raises:
        PlausibilityError: the answer is implausible and ``opts.accept_implausible`` is off.
        ObservabilityError: the same, on motion about one axis only.
    """
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
    cons, sens = Consistency(), Sensitivity()
    if opts.consistency_segments >= 2:
        say(f"consistency: {opts.consistency_segments} segments calibrated on their own")
        cons = segment_consistency(s, opts.model, pos, opts.consistency_segments,
                                   opts.max_iterations)
    if opts.sensitivity:
        say("sensitivity: IMU noise densities x3 and x1/3")
        sens = noise_sensitivity(s, opts.model, pos, max_iterations=opts.max_iterations,
                                 priors=opts.priors)
    total = _inflate(r, cons, sens)
    r.consistency, r.sensitivity = cons.to_dict(), sens.to_dict(total)


#: Result field of each sigma and the sensitivity's name for it.
_SIGMAS = {"R_MI": "sigma_rotation", "p_MI": "sigma_translation", "t_d": "sigma_time_offset",
           "gyro_bias": "sigma_gyro_bias", "accel_bias": "sigma_accel_bias",
           "gravity": "sigma_gravity"}


def _inflate(r: CalibrationResult, cons: Consistency, sens: Sensitivity) -> dict[str, Array]:
    """The reported sigmas, from the statistical ones:

    1. times the segments' Birge ratio where they disagree significantly (the others share
       the model error the segments reveal and take the largest factor);
    2. with the shift under noise densities x3 / x1/3 beyond chance added in quadrature: the
       session cannot tell the densities to better than that, so the answer is not known
       better either;
    3. and never below the largest plain move under those densities: a reweighted estimator
       is noisier (its sandwich variance is larger), so part of its move is chance, but a user
       who assumed the other densities would get that answer, and the sigma should cover it.

    Returns the reported sigma of every parameter (for the sensitivity in those sigmas).
    """
    f = {k: cons.inflation(k) for k in ("R_MI", "p_MI", "t_d")}
    worst = max(f.values(), default=1.0)
    total: dict[str, Array] = {}
    for param, attr in _SIGMAS.items():
        v = getattr(r, attr)
        if v is None:
            continue
        v = np.atleast_1d(np.asarray(v, dtype=float)) * f.get(param, worst)
        sys, move = sens.systematic(param), sens.largest_move(param)
        if sys is not None and sys.shape == v.shape:
            v = np.sqrt(v**2 + sys**2)
        if move is not None and move.shape == v.shape:
            v = np.maximum(v, move)
        total[param] = v
        setattr(r, attr, float(v[0]) if param == "t_d" else v)
    if worst > 1.0:
        scaled = ", ".join(f"{k} x{v:.2f}" for k, v in f.items() if v > 1.0)
        r.notes.append(f"the {len(cons.segments)} segments disagree beyond their own sigmas: "
                       f"sigmas scaled by their Birge ratio ({scaled}; the others "
                       f"x{worst:.2f})")
    if sens.shift:
        r.notes.append("sigmas include the shift under IMU noise densities x3 and x1/3 "
                       "(beyond chance, added in quadrature) and cover its plain move")
    return total
