"""``calibrate``: read the inputs, calibrate, write the result, report and recording."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import mocap_calib
from mocap_calib.core.model.preint import search_sorted
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.params import group, param
from mocap_calib.core.pipeline.calibrate import (
    IterationFn,
    ProgressFn,
    Recording,
    calibrate_takes,
)
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import Interrupted
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import load_plausible, save_result, save_text
from mocap_calib.report.text import summary_table
from mocap_calib.workflows.outputs import OutputPlan, Product, output, write_products
from mocap_calib.workflows.report_files.provenance import RunClock
from mocap_calib.workflows.session import (
    InputSpec,
    LoadedSession,
    NoiseSpec,
    load_priors,
    load_session,
)

HTML_HELP = ("also write a self-contained HTML report (tables and plots, opens offline in any "
             "browser; render it to a picture with scripts/render_report.sh)")
QUIET_HELP = "no progress lines"


@dataclass
class CalibrateOutputs:
    """Files a ``calibrate`` run writes (``out`` always, the others when given)."""

    out: Path = output(Path("calib.yaml"), "result YAML to write", metavar="PATH")
    report: Path | None = output(None, "also write the summary (estimates, 1-sigma, stage "
                                 "figures, notes) as a text report", metavar="PATH",
                                 show_default=False)
    rrd: Path | None = output(None, "also write a rerun recording of residuals and "
                              "trajectories", metavar="PATH", show_default=False)
    html: Path | None = output(None, HTML_HELP, metavar="PATH", show_default=False)
    quiet: bool = param(False, QUIET_HELP, decls=("--quiet", "-q"))


@dataclass
class CalibrateRequest:
    """Everything ``calibrate`` can be told: inputs, noise model, calibration options, priors,
    plausibility limits and outputs."""

    inputs: InputSpec = group(InputSpec, "Input")
    noise: NoiseSpec = group(NoiseSpec, "Noise model")
    options: CalibrationOptions = group(CalibrationOptions, "Calibration")
    prior: tuple[Path, ...] = param(
        (), "earlier result YAML as a prior (repeatable; two or more give a trend)",
        metavar="PATH", show_default=False)
    plausible: Path | None = param(
        None, "YAML file overriding the plausibility limits (docs/diagnosis.md)",
        metavar="PATH", show_default=False)
    outputs: CalibrateOutputs = group(CalibrateOutputs, "Output")

    def plan(self) -> OutputPlan:
        return OutputPlan.of(self)


def run_calibration(request: CalibrateRequest, progress: ProgressFn | None = None,
                    on_iteration: IterationFn | None = None, extra_priors: list | None = None,
                    ) -> tuple[CalibrationResult, LoadedSession]:
    """Read the inputs and calibrate (several takes together when given); returns the result
    and what was read (the first take's, for recordings and reports)."""
    opts = request.options
    t0 = time.perf_counter()
    startup = t0 - mocap_calib.IMPORTED_AT
    _warm_kernels()
    sessions = [load_session(spec, opts.time_offset) for spec in request.inputs.takes()]
    t_read = time.perf_counter() - t0
    for session in sessions:
        for note in session.notes:
            if progress is not None:
                progress(note)
    first = sessions[0]
    plausible = (opts.plausible if request.plausible is None
                 else load_plausible(request.plausible))
    priors = (load_priors(request.prior, first.imu.time_origin_ns, plausible)
              if request.prior else [])
    opts = replace(opts, noise=request.noise.resolve(first.sensor_noise,
                                                     NoiseSpec.sensor_file(request.inputs)),
                   priors=[*opts.priors, *priors, *(extra_priors or [])], plausible=plausible)
    recordings = [Recording(s.imu, s.mocap, *_names(spec))
                  for s, spec in zip(sessions, request.inputs.takes(), strict=True)]
    if opts.model.auto:
        # The diagnosis (and its filters, scipy.signal) only for `--model auto`: ~50 MB and
        # ~0.3 s of start-up that a default run does not need.
        from mocap_calib.core.diagnosis.auto import calibrate_auto

        result = calibrate_auto(recordings, opts, progress=progress, on_iteration=on_iteration)
    else:
        result = calibrate_takes(recordings, opts, progress=progress, on_iteration=on_iteration)
    result.session["inputs"] = [n for s in sessions for n in s.notes]
    result = replace(result, solver=result.solver.with_steps(
        first={"startup": round(startup, 3), "read": round(t_read, 3)}))
    if progress is not None:
        progress("time per step: " + ", ".join(
            f"{k.replace('_', ' ')} {v:.1f} s" for k, v in result.solver.step_seconds.items()))
    return result, first


def _warm_kernels() -> None:
    """Start numba's runtime while the inputs are read: the first kernel a process loads
    starts it (0.2-0.3 s, mostly imports), and the readers spend much of their time outside
    the GIL. A failure here is left to the calibration's first kernel to report, a stop to
    the main thread's next check (the request stays set; raised here, it would only print a
    thread's traceback)."""
    def load() -> None:
        try:
            search_sorted(np.zeros(2), np.zeros(1))
        except Interrupted:
            return
        except Exception:  # noqa: BLE001  (reported by the first real call)
            pass

    threading.Thread(target=load, name="kernel-warm-up", daemon=True).start()


def _names(spec: InputSpec) -> tuple[str, str]:
    """How a take's inputs are named in the result (as given)."""
    if spec.mav0:
        return str(spec.mav0[0]), str(spec.mav0[0])
    return str(spec.imu[0]), str(spec.mocap[0])


@dataclass
class CalibrateRun:
    """What :func:`calibrate_to_files` did: the result, its summary and the files written."""

    result: CalibrationResult
    summary: str
    written: list[str] = field(default_factory=list)


def calibrate_to_files(request: CalibrateRequest,
                       progress: ProgressFn | None = None) -> CalibrateRun:
    """The ``calibrate`` command: check the outputs, calibrate, write result/report/recording
    (the result file last, so that an interrupted run leaves no result behind)."""
    clock = RunClock()
    outputs = request.outputs
    request.plan().check()
    result, session = run_calibration(request, progress)
    table = summary_table(result)
    from functools import cache

    @cache
    def series():
        """What --rrd and --html draw, computed once, by the first of them to be written."""
        from mocap_calib.core.diagnosis.outputs import output_series

        return output_series(result, recording=outputs.rrd is not None,
                             report=outputs.html is not None, imu=session.imu,
                             mocap=session.mocap)

    def recording() -> None:
        from mocap_calib.viz.recording import write_calibration_recording

        write_with(outputs.rrd, lambda tmp: write_calibration_recording(tmp, result, series()))

    def html() -> None:
        from mocap_calib.workflows.report_files.pages import write_calibration_html

        write_calibration_html(outputs.html, result, series(), [
            *request.inputs.sources(), request.noise.noise, *request.prior], clock)

    written = write_products([
        Product("--out", outputs.out, lambda: save_result(outputs.out, result)),
        None if outputs.rrd is None else Product(
            "--rrd", outputs.rrd, recording, f"open with: mocap-calib view {outputs.rrd}",
            "writing rerun recording"),
        None if outputs.report is None else Product("--report", outputs.report, lambda: save_text(
            outputs.report, f"mocap-calib calibration report\n\n{table}\n")),
        None if outputs.html is None else Product("--html", outputs.html, html,
                                                  step="writing HTML report"),
    ], progress)
    return CalibrateRun(result, table, [p.line() for p in written])
