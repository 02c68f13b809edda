"""The HTML reports of the commands: the pages drawn from a result and the series computed with
it (:class:`~mocap_calib.core.result.series.OutputSeries`), their provenance, and the file.

The series are computed by the core (``core/diagnosis/outputs.py``), the drawing is
:mod:`mocap_calib.report.html`'s; nothing here computes a figure.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.series import OutputSeries
from mocap_calib.io.yaml_io import save_text
from mocap_calib.report.html import Provenance, Section, render_html
from mocap_calib.workflows.report_files.provenance import RunClock, provenance

if TYPE_CHECKING:
    from mocap_calib.core.diagnosis.report import DiagnoseReport

__all__ = ["write_report", "RunClock"]


def write_report(path: Path, title: str, sections: Sequence[Section], inputs: Sequence[Path | None],
                 clock: RunClock, subtitle: str = "",
                 verdict: tuple[str, str] | None = None) -> Path:
    """Render the page with its provenance and write it (atomically; a one-line error if the
    file cannot be written)."""
    prov: Provenance = provenance(inputs, clock)
    return save_text(path, render_html(title, sections, prov, subtitle, verdict))


def calibration_verdict(result: CalibrationResult) -> tuple[str, str] | None:
    """The plausibility verdict as a badge (text, ok/bad)."""
    if result.plausibility is None:
        return None
    v = result.plausibility.verdict
    return (f"plausibility: {v}", "ok" if v == "plausible" else "bad")


def _every_take(sections: list[Section], series: OutputSeries,
                title: str = "") -> list[Section]:
    """With several takes, the sections drawn from the solver's series (residuals,
    trajectory) are the first take's: say so, and add every other take's (titles after
    ``title``, the prefix the page gives the result's sections)."""
    from mocap_calib.report.html import take_sections

    others = series.takes[1:]
    if not others:
        return sections
    out = [replace(s, title=f"{title}Take 1: {s.title.removeprefix(title)}")
           if s.id in ("sec-residuals", "sec-trajectory") else s for s in sections]
    for k, take in enumerate(others, start=2):
        out += [replace(s, title=title + s.title) for s in take_sections(take, k)]
    return out


def write_calibration_html(path: Path, result: CalibrationResult, series: OutputSeries,
                           inputs: Sequence[Path | None], clock: RunClock) -> Path:
    """The ``calibrate --html`` page: ``series`` computed with the result
    (``core.diagnosis.outputs.output_series(result, report=True)``)."""
    from mocap_calib.report.html import calibration_sections

    sections = _every_take(calibration_sections(result, series), series)
    sub = (f"model {result.model}; {result.session.get('duration_s', '?')} s of session, "
           f"{result.session.get('imu_samples', '?')} IMU samples, "
           f"{result.session.get('mocap_samples', '?')} mocap poses")
    return write_report(path, "mocap-calib calibration report", sections, inputs, clock, sub,
                        calibration_verdict(result))


def write_diagnosis_html(path: Path, report: DiagnoseReport, series: OutputSeries,
                         inputs: Sequence[Path | None], clock: RunClock) -> Path:
    """The ``diagnose --html`` page: the steps, then the final calibration's sections
    (``series`` computed with it: ``core.diagnosis.outputs.diagnosis_series(report,
    html=True)``)."""
    from mocap_calib.report.html import diagnosis_sections

    sections = _every_take(diagnosis_sections(report, series), series, "Final calibration: ")
    clean = not report.found and not getattr(report, "unexplained", None)
    verdict = (f"diagnosis: {report.verdict}", "ok" if clean else "warn")
    sub = f"start model {report.start_model}, final model {report.final_model}"
    return write_report(path, "mocap-calib model diagnosis report", sections, inputs, clock, sub,
                        verdict)


def write_batch_report(path: Path | str, sessions: Sequence[dict], fleet: dict | None,
                       clock: RunClock | None = None) -> Path:
    """The ``batch --html`` page: ``sessions`` are the batch file's entries (``result``: the
    session's result YAML relative to the page's folder), ``fleet`` the fleet summary's plain
    data (None: none). Results that cannot be read are listed without numbers."""
    from mocap_calib.errors import CalibrationError, Interrupted
    from mocap_calib.io.yaml_io import load_result
    from mocap_calib.report.html import batch_sections

    path = Path(path)
    results, files = {}, []
    for s in sessions:
        rel = s.get("result")
        if not rel:
            continue
        f = path.parent / rel
        try:
            results[str(s.get("id"))] = load_result(f)
            files.append(f)
        except Interrupted:
            raise
        except (CalibrationError, OSError):
            continue
    n = len(sessions)
    sub = f"{n} sessions, {len(results)} results, {n - len(results)} without"
    verdict = ("all sessions calibrated", "ok") if len(results) == n else (
        f"{n - len(results)} of {n} sessions without a result", "warn")
    return write_report(path, "mocap-calib batch report", batch_sections(sessions, results, fleet),
                        files, clock or RunClock(), sub, verdict)
