"""``diagnose``: read the inputs, run the model diagnosis, write the report and recording."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, DiagnoseReport
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, Model
from mocap_calib.core.model.plausible import PlausibleLimits
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import ProgressFn
from mocap_calib.core.policy import GRAVITY
from mocap_calib.errors import InputError
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import check_writable, load_plausible, save_yaml
from mocap_calib.report.text import diagnose_table
from mocap_calib.workflows.html.provenance import RunClock
from mocap_calib.workflows.session import InputSpec, load_session, resolve_noise


def diagnose_options(*, start: str = "base", candidates: str | None = None, alpha: float = 0.01,
                     max_steps: int = 4, gravity: float = GRAVITY,
                     window: float = 5.0, plausible: Path | None = None) -> DiagnoseOptions:
    """Diagnosis options from the command line's values (checked; ``plausible``: a file of
    limits overriding the defaults of docs/diagnosis.md)."""
    if not 0.0 < alpha < 0.5:
        raise InputError(f"--alpha {alpha}: must be between 0 and 0.5, e.g. 0.01")
    if max_steps < 1:
        raise InputError(f"--max-steps {max_steps}: must be at least 1")
    cands = CANONICAL_EFFECTS if candidates is None else Model.parse(candidates).effects
    limits = PlausibleLimits() if plausible is None else load_plausible(plausible)
    return DiagnoseOptions(start=Model.parse(start), candidates=tuple(cands), alpha=alpha,
                           max_steps=max_steps, plausible=limits,
                           calibration=CalibrationOptions(gravity=gravity, window=window,
                                                          plausible=limits))


def run_diagnosis(spec: InputSpec, options, noise_file: Path | None = None,
                  noise_overrides: dict[str, float | None] | None = None,
                  progress: ProgressFn | None = None):
    """Read the inputs and run the model diagnosis; returns the report and what was read."""
    from mocap_calib.core.diagnosis.diagnose import diagnose

    session = load_session(spec)
    for note in session.notes:
        if progress is not None:
            progress(note)
    noise = resolve_noise(session, noise_file, noise_overrides or {})
    opts = replace(options, calibration=replace(options.calibration, noise=noise))
    report = diagnose(session.imu, session.mocap, opts, progress=progress)
    report.final.session["inputs"] = list(session.notes)
    return report, session


def diagnose_series(report) -> list[tuple[str, dict]]:
    """Residual series of every diagnosis step, for the rerun recording: the low-band
    measured-minus-predicted gyro and accel, and the position-factor innovations."""
    from mocap_calib.core.stages.figures import ResidualSeries

    out = []
    for i, step in enumerate(report.steps):
        series: dict = {}
        ra = step.residuals.analysis
        if ra is not None and len(ra.t):
            w = ra.keep.astype(float)
            series["gyro_lowpass"] = ResidualSeries(ra.t, ra.gyro_lp, ra.gyro_lp, w, "rad/s")
            series["accel_lowpass"] = ResidualSeries(ra.t, ra.accel_lp, ra.accel_lp, w, "m/s^2")
        if "position" in step.series:
            series["position"] = step.series["position"]
        label = f"{i}_{step.model}" if i < len(report.steps) - 1 else f"{i}_final_{step.model}"
        out.append((label, series))
    return out


@dataclass
class DiagnoseRun:
    report: DiagnoseReport
    summary: str
    written: list[str] = field(default_factory=list)


def diagnose_to_files(spec: InputSpec, options: DiagnoseOptions, out: Path, rrd: Path | None,
                      noise_file: Path | None = None,
                      progress: ProgressFn | None = None, html: Path | None = None) -> DiagnoseRun:
    """The ``diagnose`` command: check the outputs, diagnose, write report, recording and
    HTML page."""
    clock = RunClock()
    check_writable(out, rrd, html)
    report, session = run_diagnosis(spec, options, noise_file, None, progress)
    if html is not None:
        from mocap_calib.workflows.html.report import write_diagnosis_html

        if progress is not None:
            progress("writing HTML report")
        write_diagnosis_html(html, report, [spec.path, spec.imu, spec.mocap, noise_file], clock)
    save_yaml(out, report.to_dict(), "mocap-calib model diagnosis report (see docs/diagnosis.md)")
    run = DiagnoseRun(report, diagnose_table(report), [f"wrote {out}"])
    if html is not None:
        run.written.append(f"wrote {html}")
    if rrd is not None:
        from mocap_calib.viz.recording import write_calibration_recording

        if progress is not None:
            progress("writing rerun recording")
        path = write_with(rrd, lambda tmp: write_calibration_recording(
            tmp, report.final, session.imu, session.mocap, diagnose_steps=diagnose_series(report)))
        run.written.append(f"wrote {path}  (open with: mocap-calib view {path})")
    return run
