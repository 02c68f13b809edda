"""``mocap-calib groundtruth``: an IMU ground-truth trajectory for evaluating VIO."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.common import (
    ACCEL_UNIT,
    COLUMNS,
    GYRO_UNIT,
    IMU,
    IMU_TOPIC,
    MAV0,
    MOCAP,
    MOCAP_FORMAT,
    MOCAP_FRAME,
    MOCAP_RATE,
    MOCAP_TOPIC,
    POSE_SOURCE,
    POSITION_UNIT,
    QUAT_ORDER,
    RIGID_BODY,
    ROTATION,
    STAMP,
    TIME_UNIT,
    Progress,
)
from mocap_calib.cli.main import app
from mocap_calib.workflows.groundtruth import run_groundtruth
from mocap_calib.workflows.session import InputSpec


@app.command(
    help="Write the IMU frame's trajectory (pose, velocity, biases) in a gravity-aligned world "
    "on the IMU clock, from the mocap and a calibration: an error-state Kalman filter and "
    "smoother fuse the calibrated IMU with the mocap, bridge short mocap gaps and leave out "
    "what is too uncertain. EuRoC state_groundtruth_estimate0 layout (or TUM), plus a YAML "
    "sidecar that says how it was made.",
    epilog="Example: mocap-calib groundtruth --imu flight.bag --mocap flight.bag --calibration "
    "calib.yaml --out gt.csv  (then: evo_ape euroc gt.csv vio.csv)",
)
def groundtruth(
    mav0: MAV0 = None,
    imu: IMU = None,
    mocap: MOCAP = None,
    calibration: Annotated[Path, typer.Option(
        help="Result YAML of 'mocap-calib calibrate' for this rig (and clock).")] = Path(
        "calib.yaml"),
    out: Annotated[Path, typer.Option(help="Trajectory file to write.")] = Path("gt.csv"),
    format: Annotated[str, typer.Option(
        "--format", help="euroc (state_groundtruth_estimate0 layout) or tum.")] = "euroc",
    rate: Annotated[float | None, typer.Option(
        help="Output rate in Hz on the IMU clock (default: at the IMU stamps).",
        show_default=False)] = None,
    noise: Annotated[Path | None, typer.Option(
        help="Noise YAML (default: the calibration's noise model).", show_default=False)] = None,
    max_position_sigma_mm: Annotated[float, typer.Option(
        help="Leave out states whose smoothed position 1-sigma exceeds this (mm).")] = 2.0,
    max_rotation_sigma_deg: Annotated[float, typer.Option(
        help="Leave out states whose smoothed attitude 1-sigma exceeds this (deg).")] = 0.1,
    pose_source: POSE_SOURCE = "auto",
    columns: COLUMNS = None,
    time_unit: TIME_UNIT = None,
    gyro_unit: GYRO_UNIT = None,
    accel_unit: ACCEL_UNIT = None,
    quat_order: QUAT_ORDER = None,
    position_unit: POSITION_UNIT = None,
    imu_topic: IMU_TOPIC = None,
    mocap_topic: MOCAP_TOPIC = None,
    mocap_frame: MOCAP_FRAME = None,
    stamp: STAMP = "header",
    mocap_format: MOCAP_FORMAT = None,
    rigid_body: RIGID_BODY = None,
    rotation: ROTATION = None,
    mocap_rate: MOCAP_RATE = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress lines.")] = False,
) -> None:
    spec = InputSpec(mav0, imu, mocap, pose_source, columns, time_unit, gyro_unit, accel_unit,
                     quat_order, position_unit, imu_topic=imu_topic, mocap_topic=mocap_topic,
                     mocap_frame=mocap_frame, stamp=stamp, mocap_format=mocap_format,
                     rigid_body=rigid_body, rotation=rotation, mocap_rate=mocap_rate)
    run = run_groundtruth(spec, calibration, out, format, rate, noise, max_position_sigma_mm,
                          max_rotation_sigma_deg, progress=Progress(quiet))
    typer.echo(run.summary())
    typer.echo(f"wrote {run.trajectory}\nwrote {run.sidecar}  (how it was made)")
