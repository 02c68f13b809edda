"""``diagnose``: read the inputs, run the model diagnosis, write the report and recording."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, DiagnoseReport
from mocap_calib.core.params import group, param
from mocap_calib.core.pipeline.calibrate import ProgressFn
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import load_plausible, save_yaml
from mocap_calib.report.text import diagnose_table
from mocap_calib.workflows.calibrate import HTML_HELP, QUIET_HELP
from mocap_calib.workflows.outputs import OutputPlan, Product, output, write_products
from mocap_calib.workflows.report_files.provenance import RunClock
from mocap_calib.workflows.session import InputSpec, NoiseSpec, load_session

#: Calibration options that the diagnosis sets itself (its model is --start-model plus what it
#: finds; it compares models without the consistency segments, never writes an implausible
#: answer and takes no priors).
NOT_OPTIONS = ("model", "segments", "accept_implausible", "trust_prior")


@dataclass
class DiagnoseOutputs:
    out: Path = output(Path("report.yaml"), "report YAML to write", metavar="PATH")
    rrd: Path | None = output(None, "also write a rerun recording with the residuals of every "
                              "step", metavar="PATH", show_default=False)
    html: Path | None = output(None, HTML_HELP, metavar="PATH", show_default=False)
    quiet: bool = param(False, QUIET_HELP, decls=("--quiet", "-q"))


@dataclass
class DiagnoseRequest:
    """Everything ``diagnose`` can be told: the inputs and noise model as ``calibrate``'s, the
    diagnosis options (with the calibration options it uses), limits and outputs."""

    inputs: InputSpec = group(InputSpec, "Input")
    noise: NoiseSpec = group(NoiseSpec, "Noise model")
    diagnosis: DiagnoseOptions = group(DiagnoseOptions, "Diagnosis")
    plausible: Path | None = param(
        None, "YAML file overriding the plausible effect magnitudes (docs/diagnosis.md); an "
        "effect outside them is listed as implausible, never as found", metavar="PATH",
        show_default=False)
    outputs: DiagnoseOutputs = group(DiagnoseOutputs, "Output")

    def plan(self) -> OutputPlan:
        return OutputPlan.of(self)


def run_diagnosis(request: DiagnoseRequest, progress: ProgressFn | None = None):
    """Read the inputs (several takes: repeated --imu/--mocap pairs or mav0 folders, as
    ``calibrate``) and run the model diagnosis; returns the report and what was read (the
    first take's, for the recording)."""
    from mocap_calib.core.diagnosis.diagnose import diagnose_takes
    from mocap_calib.core.pipeline.calibrate import Recording

    options = request.diagnosis
    specs = request.inputs.takes()
    sessions = [load_session(spec, options.calibration.time_offset) for spec in specs]
    notes = [n for s in sessions for n in s.notes]
    for note in notes:
        if progress is not None:
            progress(note)
    first = sessions[0]
    noise = request.noise.resolve(first.sensor_noise, NoiseSpec.sensor_file(request.inputs))
    cal = replace(options.calibration, noise=noise)
    if request.plausible is not None:
        limits = load_plausible(request.plausible)
        cal = replace(cal, plausible=limits)
        options = replace(options, plausible=limits)
    recordings = [Recording(s.imu, s.mocap, *_names(spec))
                  for s, spec in zip(sessions, specs, strict=True)]
    report = diagnose_takes(recordings, replace(options, calibration=cal), progress=progress)
    report.final.session["inputs"] = notes
    return report, first


def _names(spec: InputSpec) -> tuple[str, str]:
    """How a take's inputs are named in the report (as given)."""
    if spec.mav0:
        return str(spec.mav0[0]), str(spec.mav0[0])
    return str(spec.imu[0]), str(spec.mocap[0])


@dataclass
class DiagnoseRun:
    report: DiagnoseReport
    summary: str
    written: list[str] = field(default_factory=list)


def diagnose_to_files(request: DiagnoseRequest,
                      progress: ProgressFn | None = None) -> DiagnoseRun:
    """The ``diagnose`` command: check the outputs, diagnose, write recording, HTML page and
    the report YAML (last)."""
    clock = RunClock()
    out, rrd, html = request.outputs.out, request.outputs.rrd, request.outputs.html
    request.plan().check()
    report, session = run_diagnosis(request, progress)

    from functools import cache

    @cache
    def series():
        """What --rrd and --html draw, computed once, by the first of them to be written."""
        from mocap_calib.core.diagnosis.outputs import diagnosis_series

        return diagnosis_series(report, recording=rrd is not None, html=html is not None,
                                imu=session.imu, mocap=session.mocap)

    def recording() -> None:
        from mocap_calib.viz.recording import write_calibration_recording

        write_with(rrd, lambda tmp: write_calibration_recording(tmp, report.final, series()))

    def page() -> None:
        from mocap_calib.workflows.report_files.pages import write_diagnosis_html

        write_diagnosis_html(html, report, series(), [*request.inputs.sources(),
                                                      request.noise.noise], clock)

    written = write_products([
        Product("--out", out, lambda: save_yaml(
            out, report.to_dict(), "mocap-calib model diagnosis report (see docs/diagnosis.md)")),
        None if html is None else Product("--html", html, page, step="writing HTML report"),
        None if rrd is None else Product("--rrd", rrd, recording,
                                         f"open with: mocap-calib view {rrd}",
                                         "writing rerun recording"),
    ], progress)
    return DiagnoseRun(report, diagnose_table(report), [p.line() for p in written])
