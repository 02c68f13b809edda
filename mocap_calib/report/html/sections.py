"""The section lists of each kind of report, and id prefixing for pages with several results."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from mocap_calib.report.html.page import Cell, Row, Section, Table, prefixed

if TYPE_CHECKING:
    from mocap_calib.core.diagnosis.diagnose import DiagnoseReport
    from mocap_calib.core.intrinsics.multipos import MultiposResult
    from mocap_calib.core.intrinsics.noise_result import AllanResult
    from mocap_calib.core.model.types import ImuSamples
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.report.html.calibration import CalibrationExtras
    from mocap_calib.report.html.intrinsics import PoseResiduals


def calibration_sections(result: CalibrationResult,
                         extras: CalibrationExtras | None = None) -> list[Section]:
    """Result table, checks (plausibility, consistency, sensitivity), clock search, residuals
    per stage with spectra, trajectory and mocap gaps. The figures from the solver's
    diagnostics need ``result.diagnostics`` (a result read from a file has none: those
    sections then say so)."""
    from mocap_calib.report.html.calibration import (
        CalibrationExtras,
        checks_section,
        clock_section,
        result_section,
    )
    from mocap_calib.report.html.residuals import residuals_section, trajectory_section

    ex = extras or CalibrationExtras()
    return [result_section(result), checks_section(result), clock_section(result),
            residuals_section(result, ex), trajectory_section(result, ex)]


def take_sections(view: CalibrationResult, take: int,
                  extras: CalibrationExtras | None = None) -> list[Section]:
    """Another take's residuals and trajectory: ``view`` is the result with that take's
    diagnostics (``result.diagnostics.takes[take - 1]``); ids and titles name the take."""
    from mocap_calib.report.html.calibration import CalibrationExtras
    from mocap_calib.report.html.residuals import residuals_section, trajectory_section

    ex = extras or CalibrationExtras()
    sections = prefixed([residuals_section(view, ex), trajectory_section(view, ex)],
                        f"take{take}-")
    return [replace(s, title=f"Take {take}: {s.title}") for s in sections]


def diagnosis_sections(report: DiagnoseReport,
                       extras: CalibrationExtras | None = None) -> list[Section]:
    """The gap per step and sensor, every candidate's statistic, the ``unexplained``
    signature when there is one, then the final calibration's sections."""
    from mocap_calib.report.html.diagnosis import diagnosis_steps_sections

    final = rekeyed(calibration_sections(report.final, extras), "final_calibration/")
    for s in final:
        s.title = f"Final calibration: {s.title}"
    return diagnosis_steps_sections(report) + final


def multipos_sections(result: MultiposResult, imu: ImuSamples,
                      residuals: PoseResiduals | None = None) -> list[Section]:
    """Intrinsics with 1-sigma, static intervals on the accel norm, per-pose residuals
    (computed by ``workflows.html_intrinsics.pose_residuals``)."""
    from mocap_calib.report.html.intrinsics import multipos_report_sections

    return multipos_report_sections(result, imu, residuals)


def allan_sections(result: AllanResult) -> list[Section]:
    """Noise parameters per axis and the Allan deviation with the fitted lines."""
    from mocap_calib.report.html.intrinsics import allan_report_sections

    return allan_report_sections(result)


def batch_sections(sessions: Sequence[Mapping[str, Any]],
                   results: Mapping[str, CalibrationResult],
                   fleet: Mapping[str, Any] | None = None) -> list[Section]:
    """A batch page: one row per session (``sessions``: the batch file's entries, with ``id``,
    ``imu_id``, ``date``, ``status``, ``seconds``, ``error``), the estimates per IMU over the
    dates, the fleet's outliers (``fleet``: the fleet summary's plain data), then the result
    and checks of every session with a result (``results`` by session id; ids prefixed
    ``s<i>-``)."""
    from mocap_calib.report.html.batch import batch_report_sections

    return batch_report_sections(sessions, results, fleet)


def rekeyed(sections: Sequence[Section], prefix: str) -> list[Section]:
    """Copies of ``sections`` whose table cells name their file keys under ``prefix`` (a
    result embedded in another file, e.g. a diagnosis report's ``final_calibration``)."""
    def block(b: Any) -> Any:
        if isinstance(b, Row):
            return Row([block(x) for x in b.blocks])
        if not isinstance(b, Table):
            return b
        rows = [[replace(c, key=prefix + c.key) if isinstance(c, Cell) and c.key is not None
                 else c for c in row] for row in b.rows]
        return replace(b, rows=rows)

    return [replace(s, blocks=[block(b) for b in s.blocks]) for s in sections]
