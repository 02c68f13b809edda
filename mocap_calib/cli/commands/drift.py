"""``mocap-calib drift``: does a calibration make gyro integration drift less?"""

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
    MOCAP,
    POSITION_UNIT,
    QUAT_ORDER,
    STAMP,
    TIME_UNIT,
    Progress,
)
from mocap_calib.cli.main import app


@app.command(
    help="Attitude-drift check: integrate the gyro over [--start, --end] (a segment not used "
    "for the calibration) raw and calibrated, from the same initial attitude, and compare roll "
    "and pitch at the end with a reference.\n\n"
    "The calibration is a 'mocap-calib calibrate' result or 'mocap-calib multipos' intrinsics. "
    "With --mocap the attitudes are the marker's turned by the calibration's T_marker_imu "
    "(needs a calibrate result); without, the IMU must rest at --start and --end and the "
    "accelerometer gives roll and pitch there.",
    epilog="Examples: mocap-calib drift --imu imu0/data.csv --calibration calib.yaml --start "
    "60 --end 120 --mocap vicon0/data.csv | mocap-calib drift --imu mp2 --calibration "
    "intrinsics.yaml --start 35 --end 95",
)
def drift(
    calibration: Annotated[Path, typer.Option(
        help="Calibration YAML: a 'calibrate' result or 'multipos' intrinsics.",
        show_default=False)],
    start: Annotated[float, typer.Option(
        help="Segment start, s after the IMU log's first sample.", show_default=False)],
    end: Annotated[float, typer.Option(
        help="Segment end, s after the IMU log's first sample.", show_default=False)],
    imu: IMU = None,
    mocap: MOCAP = None,
    out: Annotated[Path | None, typer.Option(
        help="Also write the figures as YAML.", show_default=False)] = None,
    static_window: Annotated[float, typer.Option(
        help="Without --mocap: window around --start/--end over which the accelerometer is "
        "averaged, s.")] = 1.0,
    columns: COLUMNS = None,
    time_unit: TIME_UNIT = None,
    gyro_unit: GYRO_UNIT = None,
    accel_unit: ACCEL_UNIT = None,
    quat_order: QUAT_ORDER = None,
    position_unit: POSITION_UNIT = None,
    imu_topic: IMU_TOPIC = None,
    stamp: STAMP = "header",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress lines.")] = False,
) -> None:
    from mocap_calib.workflows.imu.drift import run_drift
    from mocap_calib.workflows.imu.imu_input import ImuSpec

    spec = ImuSpec(imu, columns, time_unit, gyro_unit, accel_unit, imu_topic, stamp)
    run = run_drift(spec, calibration, start, end, mocap=mocap, quat_order=quat_order,
                    position_unit=position_unit, static_window_s=static_window, out=out,
                    progress=Progress(quiet))
    typer.echo(run.summary())
    if out is not None:
        typer.echo(f"\nwrote {out}")
