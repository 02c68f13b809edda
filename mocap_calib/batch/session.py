"""One session of a batch: the ``calibrate`` options it was given, and the function a worker
runs on it.

:class:`CalibrateArgs` holds the options of ``mocap-calib calibrate`` by their long names with
underscores (the manifest's keys) and :func:`calibrate_args` does what that command does with
them (build the input spec, the options and the noise overrides; read and calibrate). A test
checks that the two option lists stay the same.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.result.calibration import CalibrationResult


@dataclass(frozen=True)
class CalibrateArgs:
    """The options of ``mocap-calib calibrate`` with its defaults (``mav0`` is its folder
    argument; ``out``, ``rrd``, ``report`` and ``quiet`` belong to the batch itself)."""

    mav0: Path | None = None
    imu: Path | None = None
    mocap: Path | None = None
    model: str = "base+time_offset"
    gravity: float = GRAVITY
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
    max_iterations: int = 30
    max_offset: float | None = None
    segments: int = 3
    accept_implausible: bool = False
    plausible: Path | None = None
    no_robust: bool = False
    pose_source: str = "auto"
    columns: str | None = None
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    quat_order: str | None = None
    position_unit: str | None = None
    imu_topic: str | None = None
    mocap_topic: str | None = None
    mocap_frame: str | None = None
    stamp: str = "header"
    mocap_format: str | None = None
    rigid_body: str | None = None
    rotation: str | None = None
    mocap_rate: float | None = None


@dataclass(frozen=True)
class SessionJob:
    """What a worker needs: the options, and (``--prior-from-history``) the earlier results of
    the same IMU as plain data with their session time set to their manifest date."""

    id: str
    args: CalibrateArgs
    history: tuple[dict[str, Any], ...] = field(default_factory=tuple)
    at_ns: int | None = None


def calibrate_args(args: CalibrateArgs, extra_priors: list | None = None) -> CalibrationResult:
    """Calibrate one session as ``mocap-calib calibrate`` does with these options (the same
    workflow calls as that command, without writing files)."""
    from dataclasses import replace

    from mocap_calib.workflows.calibrate import (
        InputSpec,
        calibration_options,
        noise_overrides,
        run_calibration,
    )

    a = args
    spec = InputSpec(a.mav0, a.imu, a.mocap, a.pose_source, a.columns, a.time_unit, a.gyro_unit,
                     a.accel_unit, a.quat_order, a.position_unit, imu_topic=a.imu_topic,
                     mocap_topic=a.mocap_topic, mocap_frame=a.mocap_frame, stamp=a.stamp,
                     mocap_format=a.mocap_format, rigid_body=a.rigid_body, rotation=a.rotation,
                     mocap_rate=a.mocap_rate)
    opts = calibration_options(model=a.model, gravity=a.gravity,
                               keyframe_spacing=a.keyframe_spacing, window=a.window,
                               time_offset=a.time_offset, robust=not a.no_robust, start=a.start,
                               end=a.end, max_iterations=a.max_iterations,
                               max_offset=a.max_offset, segments=a.segments,
                               accept_implausible=a.accept_implausible, plausible=a.plausible)
    if extra_priors:
        opts = replace(opts, priors=[*opts.priors, *extra_priors])
    overrides = noise_overrides(gyro_noise=a.gyro_noise, gyro_walk=a.gyro_walk,
                                accel_noise=a.accel_noise, accel_walk=a.accel_walk,
                                mocap_noise_mm=a.mocap_noise_mm, mocap_noise_deg=a.mocap_noise_deg)
    result, _ = run_calibration(spec, opts, a.noise, overrides, list(a.prior))
    return result


def history_priors(history: tuple[dict[str, Any], ...], at_ns: int | None) -> list:
    """Priors from the earlier results of the same IMU (a trend from two dates or more), as
    ``--prior`` gives them."""
    from mocap_calib.core.result.priors import priors_from_results

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
