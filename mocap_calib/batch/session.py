"""One session of a batch: the ``calibrate`` options it was given, and the function a worker
runs on it.

:class:`CalibrateArgs` holds the options of ``mocap-calib calibrate`` by their long names with
underscores (the manifest's keys) and :func:`calibrate_args` does what that command does with
them (build the input spec, the options and the noise overrides; read and calibrate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mocap_calib.core.calib.result import CalibrationResult


@dataclass(frozen=True)
class CalibrateArgs:
    """The options of ``mocap-calib calibrate`` with its defaults (``mav0`` is its folder
    argument); ``rigid_body`` picks one body of a multi-body mocap export."""

    mav0: Path | None = None
    imu: Path | None = None
    mocap: Path | None = None
    rigid_body: str | None = None
    model: str = "base+time_offset"
    gravity: float = 9.81
    noise: Path | None = None
    gyro_noise: float | None = None
    gyro_walk: float | None = None
    accel_noise: float | None = None
    accel_walk: float | None = None
    mocap_noise_mm: float | None = None
    mocap_noise_deg: float | None = None
    keyframe_spacing: float = 0.5
    window: float = 5.0
    time_offset: float | None = None
    prior: tuple[Path, ...] = ()
    start: float | None = None
    end: float | None = None
    no_robust: bool = False
    pose_source: str = "auto"
    columns: str | None = None
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    quat_order: str | None = None
    position_unit: str | None = None


@dataclass(frozen=True)
class SessionJob:
    """What a worker needs: the options, and (``--prior-from-history``) the earlier results of
    the same IMU as plain data with their session time set to their manifest date."""

    id: str
    args: CalibrateArgs
    history: tuple[dict[str, Any], ...] = field(default_factory=tuple)
    at_ns: int | None = None


def calibrate_args(args: CalibrateArgs, extra_priors: list | None = None) -> CalibrationResult:
    """Calibrate one session as ``mocap-calib calibrate`` would with these options.

    Mirrors the CLI command's body; when the workflow gains one ``run_calibrate(...)`` that
    takes the options, this becomes a call to it.
    """
    from mocap_calib.core.calib.pipeline import CalibrationOptions
    from mocap_calib.core.model.effects import Model
    from mocap_calib.workflows.calibrate import InputSpec, run_calibration

    spec = InputSpec(args.mav0, args.imu, args.mocap, args.pose_source, args.columns,
                     args.time_unit, args.gyro_unit, args.accel_unit, args.quat_order,
                     args.position_unit, rigid_body=args.rigid_body)
    opts = CalibrationOptions(
        model=Model.parse(args.model), gravity=args.gravity,
        attitude_spacing=args.keyframe_spacing, velocity_spacing=args.keyframe_spacing,
        window=args.window, time_offset=args.time_offset, robust=not args.no_robust,
        start=args.start, end=args.end, priors=list(extra_priors or []))
    overrides = {
        "gyroscope_noise_density": args.gyro_noise, "gyroscope_random_walk": args.gyro_walk,
        "accelerometer_noise_density": args.accel_noise,
        "accelerometer_random_walk": args.accel_walk,
        "mocap_position_sigma": None if args.mocap_noise_mm is None else args.mocap_noise_mm * 1e-3,
        "mocap_rotation_sigma": (None if args.mocap_noise_deg is None
                                 else math.radians(args.mocap_noise_deg)),
    }
    result, _ = run_calibration(spec, opts, args.noise, overrides, list(args.prior))
    return result


def history_priors(history: tuple[dict[str, Any], ...], at_ns: int | None) -> list:
    """Priors from the earlier results of the same IMU (a trend from two dates or more), as
    ``--prior`` gives them."""
    from mocap_calib.core.calib.priors import priors_from_results

    if not history:
        return []
    results = [CalibrationResult.from_dict(d) for d in history]
    times = {r.session.get("imu_start_ns") for r in results}
    if len(times) < 2:  # all from one date: no trend, the latest one stands for them
        return priors_from_results(results[-1:], None)
    return priors_from_results(results, at_ns)


def run_session(job: SessionJob) -> CalibrationResult:
    """The worker's function: calibrate, drop what is only for inspection, return the result."""
    result = calibrate_args(job.args, history_priors(job.history, job.at_ns))
    result.diagnostics = None  # residual series: large, and not part of the result file
    return result
