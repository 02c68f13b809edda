"""``--model auto``: the model is the one the diagnosis arrives at (the same tests, gates and
final calibration as ``diagnose``), so that the two never give different answers. With
several takes every take is diagnosed, and an effect is kept only when every take shows it.
"""

from __future__ import annotations

import time
from dataclasses import replace

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose
from mocap_calib.core.diagnosis.report import DiagnoseReport
from mocap_calib.core.model.effects import Model
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import (
    IterationFn,
    ProgressFn,
    Recording,
    calibrate_takes,
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
    reports: list[DiagnoseReport] = []
    for k, rec in enumerate(recordings):
        if len(recordings) > 1:
            say(f"--model auto: diagnosing take {k + 1} of {len(recordings)}")
        else:
            say("--model auto: the diagnosis chooses the effects")
        reports.append(diagnose(rec.imu, rec.mocap, dopts, progress=say))
    found = [e for e in reports[0].found if all(e in r.found for r in reports[1:])]
    model = Model(tuple(found))
    say(f"--model auto: {model}")
    if len(recordings) == 1:
        # The diagnosis' final calibration is this model's (it accepts implausible answers
        # to report them; the user's choice applies here).
        result = reports[0].final
        failed = () if result.plausibility is None else result.plausibility.failed
        if failed and not options.accept_implausible:
            reasons = "; ".join(failed)
            raise PlausibilityError(
                f"implausible calibration: {reasons}; check the inputs' units, conventions and "
                "clock, or pass --accept-implausible to write it marked as such")
        result = replace(result, notes=tuple(n for n in result.notes
                                             if not n.startswith("IMPLAUSIBLE")))
    else:
        result = calibrate_takes(recordings, replace(options, model=model), progress,
                                 on_iteration)
    # The diagnosis' time, its final calibration's steps included once.
    seconds = round(time.perf_counter() - t0 - float(result.solver.total_seconds or 0.0), 3)
    return replace(result, model_selection=_selection(reports, found),
                   solver=result.solver.with_steps(last={"model_selection": seconds}),
                   degraded=(*result.degraded, *(x for r in reports for x in r.degraded)))


def _selection(reports: list[DiagnoseReport], found: list[str]) -> ModelSelection:
    """What the result says of the choice: the tests of every step (the first take's, and
    each take's found effects when several)."""
    r = reports[0]
    return ModelSelection(
        chosen=str(Model(tuple(found))),
        method="model diagnosis (docs/diagnosis.md): at each step the candidate with the "
               "strongest evidence is added when significant (Bonferroni over the "
               "candidates) and plausible",
        threshold_log10_p=round(r.threshold_log10_p, 3),
        steps=tuple(SelectionStep(s.model, s.added, tuple((c.effect, round(c.log10_p, 2))
                                                          for c in s.candidates[:4]))
                    for s in r.steps),
        implausible=tuple(r.implausible),
        found_per_take=(tuple(tuple(x.found) for x in reports) if len(reports) > 1
                        else None))
