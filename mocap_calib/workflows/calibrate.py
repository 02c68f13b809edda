"""``calibrate``: read the inputs, calibrate, write the result, report and recording."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.plausible import PlausibleLimits
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import IterationFn, ProgressFn, calibrate
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import check_writable, load_plausible, save_result, save_text
from mocap_calib.report.text import summary_table
from mocap_calib.workflows.html.provenance import RunClock
from mocap_calib.workflows.session import (
    InputSpec,
    LoadedSession,
    load_priors,
    load_session,
    resolve_noise,
)

__all__ = ["InputSpec", "LoadedSession", "load_session", "resolve_noise", "run_calibration",
           "calibrate_to_files", "calibration_options", "noise_overrides", "effects_help"]


def effects_help() -> str:
    """One line per effect of the ladder, for ``--model``'s help."""
    return "; ".join(f"{e.name} ({e.description})" for e in EFFECTS.values())


def calibration_options(*, model: str = "base+time_offset", gravity: float = GRAVITY,
                        keyframe_spacing: float = 0.5, window: float = 5.0,
                        time_offset: float | None = None, robust: bool = True,
                        start: float | None = None, end: float | None = None,
                        max_iterations: int = 30, max_offset: float | None = None,
                        segments: int = 3, accept_implausible: bool = False,
                        plausible: Path | None = None) -> CalibrationOptions:
    """Calibration options from the command line's values (``plausible``: a limits file)."""
    if max_offset is not None and not max_offset > 0:
        raise InputError(f"--max-offset {max_offset}: give a positive search range in s")
    if not (segments == 0 or 2 <= segments <= 20):
        raise InputError(f"--segments {segments}: give 0 (no consistency check) or 2-20")
    return CalibrationOptions(
        model=Model.parse(model), gravity=gravity, attitude_spacing=keyframe_spacing,
        velocity_spacing=keyframe_spacing, window=window, time_offset=time_offset,
        robust=robust, start=start, end=end, max_iterations=max_iterations,
        max_offset=max_offset, consistency_segments=segments,
        accept_implausible=accept_implausible,
        plausible=PlausibleLimits() if plausible is None else load_plausible(plausible))


def noise_overrides(*, gyro_noise: float | None = None, gyro_walk: float | None = None,
                    accel_noise: float | None = None, accel_walk: float | None = None,
                    mocap_noise_mm: float | None = None,
                    mocap_noise_deg: float | None = None) -> dict[str, float | None]:
    """Noise-model fields given on the command line (None: not given), in SI units."""
    return {
        "gyroscope_noise_density": gyro_noise, "gyroscope_random_walk": gyro_walk,
        "accelerometer_noise_density": accel_noise, "accelerometer_random_walk": accel_walk,
        "mocap_position_sigma": None if mocap_noise_mm is None else mocap_noise_mm * 1e-3,
        "mocap_rotation_sigma": (None if mocap_noise_deg is None
                                 else float(np.radians(mocap_noise_deg))),
    }


def run_calibration(spec: InputSpec, options: CalibrationOptions, noise_file: Path | None = None,
                    noise_overrides: dict[str, float | None] | None = None,
                    prior_files: list[Path] | None = None, progress: ProgressFn | None = None,
                    on_iteration: IterationFn | None = None,
                    ) -> tuple[CalibrationResult, LoadedSession]:
    """Read the inputs and calibrate; returns the result and what was read."""
    session = load_session(spec)
    for note in session.notes:
        if progress is not None:
            progress(note)
    noise = resolve_noise(session, noise_file, noise_overrides or {})
    priors = load_priors(prior_files, session.imu.time_origin_ns) if prior_files else []
    opts = replace(options, noise=noise, priors=[*options.priors, *priors])
    result = calibrate(session.imu, session.mocap, opts, progress=progress,
                       on_iteration=on_iteration)
    result.session["inputs"] = list(session.notes)
    return result, session


@dataclass
class CalibrateOutputs:
    """Files a ``calibrate`` run writes (``out`` always, the others when given)."""

    out: Path
    report: Path | None = None
    rrd: Path | None = None
    html: Path | None = None


@dataclass
class CalibrateRun:
    """What :func:`calibrate_to_files` did: the result, its summary and the files written."""

    result: CalibrationResult
    summary: str
    written: list[str] = field(default_factory=list)


def calibrate_to_files(spec: InputSpec, options: CalibrationOptions, outputs: CalibrateOutputs,
                       noise_file: Path | None = None,
                       overrides: dict[str, float | None] | None = None,
                       prior_files: list[Path] | None = None,
                       progress: ProgressFn | None = None) -> CalibrateRun:
    """The ``calibrate`` command: check the outputs, calibrate, write result/report/recording."""
    clock = RunClock()
    check_writable(outputs.out, outputs.report, outputs.rrd, outputs.html)
    result, session = run_calibration(spec, options, noise_file, overrides, prior_files or [],
                                      progress)
    # The result file is written last, so that an interrupted run leaves no result behind.
    table = summary_table(result)
    run = CalibrateRun(result, table, [])
    if outputs.rrd is not None:
        from mocap_calib.viz.recording import write_calibration_recording

        if progress is not None:
            progress("writing rerun recording")
        path = write_with(outputs.rrd, lambda tmp: write_calibration_recording(
            tmp, result, session.imu, session.mocap))
        run.written.append(f"wrote {path}  (open with: mocap-calib view {path})")
    if outputs.report is not None:
        save_text(outputs.report, f"mocap-calib calibration report\n\n{table}\n")
        run.written.append(f"wrote {outputs.report}")
    if outputs.html is not None:
        from mocap_calib.workflows.html.report import write_calibration_html

        if progress is not None:
            progress("writing HTML report")
        write_calibration_html(outputs.html, result, [spec.path, spec.imu, spec.mocap,
                                                      noise_file, *(prior_files or [])], clock)
        run.written.append(f"wrote {outputs.html}")
    save_result(outputs.out, result)
    run.written.insert(0, f"wrote {outputs.out}")
    return run
