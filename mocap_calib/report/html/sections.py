"""The section lists of each kind of report, and id prefixing for pages with several results."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from mocap_calib.report.html.page import Cell, Row, Section, Table, prefixed

if TYPE_CHECKING:
    from mocap_calib.core.intrinsics.multipos.result import MultiposResult
    from mocap_calib.core.intrinsics.noise_result import AllanResult
    from mocap_calib.core.model.types import ImuSamples
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.core.result.series import OutputSeries, TakeSeries
    from mocap_calib.report.html.diagnosis import DiagnosisRecord
    from mocap_calib.report.html.intrinsics import PoseResiduals


def calibration_sections(result: CalibrationResult,
                         series: OutputSeries | None = None) -> list[Section]:
    """Result table, checks (plausibility, consistency, sensitivity), clock search, residuals
    per stage with spectra, trajectory and mocap gaps. The figures beyond the result file
    are drawn from ``series`` (computed with the result for the outputs; its first take);
    without it (a result read from a file) those sections say they are not available."""
    from mocap_calib.report.html.calibration import (
        checks_section,
        clock_section,
        result_section,
    )
    from mocap_calib.report.html.residuals import residuals_section, trajectory_section

    first = series.first if series is not None else None
    return [result_section(result), checks_section(result),
            clock_section(result, series.clock if series is not None else None),
            residuals_section(first), trajectory_section(first)]


def take_sections(take: TakeSeries, k: int) -> list[Section]:
    """Take ``k``'s residuals and trajectory (``take``: its series); ids and titles name the
    take."""
    from mocap_calib.report.html.residuals import residuals_section, trajectory_section

    sections = prefixed([residuals_section(take), trajectory_section(take)], f"take{k}-")
    return [replace(s, title=f"Take {k}: {s.title}") for s in sections]


def diagnosis_sections(report: DiagnosisRecord,
                       series: OutputSeries | None = None) -> list[Section]:
    """The gap per step and sensor, every candidate's statistic, the ``unexplained``
    signature when there is one, then the final calibration's sections (``series``: computed
    with the final calibration)."""
    from mocap_calib.report.html.diagnosis import diagnosis_steps_sections

    final = rekeyed(calibration_sections(report.final, series), "final_calibration/")
    for s in final:
        s.title = f"Final calibration: {s.title}"
    return diagnosis_steps_sections(report) + final


def multipos_sections(result: MultiposResult, imu: ImuSamples,
                      residuals: PoseResiduals | None = None) -> list[Section]:
    """Intrinsics with 1-sigma, static intervals on the accel norm, per-pose residuals
    (computed by ``workflows.report_files.intrinsics.pose_residuals``)."""
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
