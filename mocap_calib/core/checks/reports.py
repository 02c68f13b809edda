"""The result's sections from the uncertainty passes: the consistency and sensitivity
sections (the numbers as the file shows them) and what ran degraded."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.parameters import ROTATION, TIME_OFFSET, TRANSLATION, Parameter
from mocap_calib.core.result.estimate import Estimate
from mocap_calib.core.result.sections import Degradation
from mocap_calib.core.result.verdicts import ConsistencyReport, SegmentRecord, SensitivityReport
from mocap_calib.core.uncertainty.segments import Consistency, SegmentEstimate
from mocap_calib.core.uncertainty.sensitivity import EFFECTS_SHOWN, MOCAP_AR1, Sensitivity

Array = NDArray[np.float64]


def segment_record(s: SegmentEstimate) -> SegmentRecord:
    """A segment as the result keeps it (span rounded to the millisecond)."""
    e = s.est
    estimates = {ROTATION: Estimate(ROTATION.value_of(e.R_MI), e.sigma[ROTATION]),
                 TRANSLATION: Estimate(e.p_MI, e.sigma[TRANSLATION]),
                 TIME_OFFSET: Estimate(None if e.t_d is None else np.array([e.t_d]),
                                       e.sigma.get(TIME_OFFSET))}
    return SegmentRecord(round(s.start_s, 3), round(s.end_s, 3), estimates, s.take, s.end_take)


def _report(c: Consistency, takes: ConsistencyReport | None = None) -> ConsistencyReport:
    return ConsistencyReport(
        tuple(segment_record(s) for s in c.segments),
        {p: round(v, 3) for p, v in c.max_z.items()},
        {p: round(v, 3) for p, v in c.birge.items()},
        {p: round(c.factor(p), 3) for p in c.max_z},
        {p: round(c.p_value(p), 4) for p in c.birge}, c.note, takes)


def consistency_report(segments: Consistency, takes: Consistency) -> ConsistencyReport:
    """The segments' comparison, with the takes' under ``takes`` when there is one."""
    return _report(segments, _report(takes) if takes.segments or takes.note else None)


def sensitivity_report(sens: Sensitivity, total: dict[Parameter, Array]) -> SensitivityReport:
    """The sensitivity section; ``total``: the reported sigmas (moves in those, too)."""
    moved = None
    if total:
        moved = {f: {p: round(float(np.max(v / total[p])), 3) for p, v in sh.items()
                     if p in total} for f, sh in sens.raw.items()}
    return SensitivityReport(
        {f: {p: round(v, 3) for p, v in m.items()} for f, m in sens.moved.items()}, moved,
        {k: round(v, 4) for k, v in sens.mocap_model.items()} or None, sens.note)


def consistency_degraded(c: Consistency, what: str, asked: bool) -> list[Degradation]:
    """The consistency check that was asked for but could not compare ``what``s."""
    if not asked or not c.note:
        return []
    return [Degradation(f"{what} consistency", c.note,
                        f"the {what}s are not compared: the sigmas carry no consistency "
                        "factor (1)")]


#: What each alternative of the sensitivity is, for a reader.
_ALTERNATIVES = {MOCAP_AR1: "the correlated mocap noise model",
                 EFFECTS_SHOWN: "the model with the effects the data show"}


def sensitivity_degraded(sens: Sensitivity) -> list[Degradation]:
    """One entry per alternative whose refit failed."""
    return [Degradation(f"sensitivity {key}",
                        f"the refit under {_ALTERNATIVES.get(key, f'IMU noise densities {key}')} "
                        f"failed ({why})",
                        "its shift is not in the sigmas, which may be too small")
            for key, why in sens.failed.items()]
