"""``--model auto``: the model is the one the diagnosis arrives at (the same tests, gates and
final calibration as ``diagnose``), so that the two never give different answers. With
several takes the diagnosis is joint, and an effect is kept only when every take's own test
shows it.
"""

from __future__ import annotations

import time
from dataclasses import replace

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose_takes
from mocap_calib.core.diagnosis.report import DiagnoseReport
from mocap_calib.core.model.effects import Model
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import (
    IterationFn,
    ProgressFn,
    Recording,
)
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.verdicts import ModelSelection, SelectionStep
from mocap_calib.errors import PlausibilityError


def calibrate_auto(recordings: list[Recording], options: CalibrationOptions,
                   progress: ProgressFn | None = None,
                   on_iteration: IterationFn | None = None) -> CalibrationResult:
    """Choose the model by the diagnosis, then calibrate with it; the result says which model
    and why (``model_selection``)."""
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    dopts = DiagnoseOptions(calibration=replace(options, model=Model()),
                            plausible=options.plausible)
    say("--model auto: the diagnosis chooses the effects"
        + (f" ({len(recordings)} takes together)" if len(recordings) > 1 else ""))
    report = diagnose_takes(recordings, dopts, progress=say, every_take=True)
    say(f"--model auto: {report.final_model}")
    # The diagnosis' final calibration is this model's (it accepts implausible answers to
    # report them; the user's choice applies here).
    result = report.final
    failed = () if result.plausibility is None else result.plausibility.failed
    if failed and not options.accept_implausible:
        reasons = "; ".join(failed)
        raise PlausibilityError(
            f"implausible calibration: {reasons}; check the inputs' units, conventions and "
            "clock, or pass --accept-implausible to write it marked as such")
    result = replace(result, notes=tuple(n for n in result.notes
                                         if not n.startswith("IMPLAUSIBLE")))
    # The diagnosis' time, its final calibration's steps included once.
    seconds = round(time.perf_counter() - t0 - float(result.solver.total_seconds or 0.0), 3)
    return replace(result, model_selection=_selection(report, len(recordings)),
                   solver=result.solver.with_steps(last={"model_selection": seconds}),
                   degraded=(*result.degraded, *report.degraded))


def _selection(r: DiagnoseReport, n_takes: int) -> ModelSelection:
    """What the result says of the choice: the tests of every step (and each take's own
    evidence for the effects found, when several)."""
    per_take: list[list[str]] = [[] for _ in range(n_takes)]
    for s in r.steps:
        best = next((c for c in s.candidates if c.effect == s.added), None)
        for row in (best.takes or []) if best is not None else []:
            if row["evidence"]:
                per_take[int(row["take"]) - 1].append(str(s.added))
    return ModelSelection(
        chosen=r.final_model,
        method="model diagnosis (docs/diagnosis.md): at each step every candidate's score "
               "test at the solution; the strongest significant one (Bonferroni over the "
               "candidates) is refitted and added when the refit confirms it, lowers the "
               "residual and is plausible",
        threshold_log10_p=round(r.threshold_log10_p, 3),
        steps=tuple(SelectionStep(s.model, s.added, tuple((c.effect, round(c.log10_p, 2))
                                                          for c in s.candidates[:4]))
                    for s in r.steps),
        implausible=tuple(r.implausible),
        found_per_take=tuple(tuple(x) for x in per_take) if n_takes > 1 else None)
