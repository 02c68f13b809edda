"""``mocap-calib drift``: does a calibration make gyro integration drift less?"""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.common import Progress
from mocap_calib.cli.main import app
from mocap_calib.workflows.imu.drift import DriftRequest, run_drift
from mocap_calib.workflows.imu.imu_input import MULTIPOS_ONLY


def _drift(request: DriftRequest) -> None:
    run = run_drift(request, progress=Progress(request.quiet))
    typer.echo(run.summary())
    if request.out is not None:
        typer.echo(f"\nwrote {request.out}")


add_command(
    app, "drift", DriftRequest, _drift, exclude=MULTIPOS_ONLY,
    help="Attitude-drift check: integrate the gyro over [--segment-start, --segment-end] (a "
    "segment not used for the calibration) raw and calibrated, from the same initial attitude, "
    "and compare roll and pitch at the end with a reference.\n\n"
    "The calibration is a 'mocap-calib calibrate' result or 'mocap-calib multipos' intrinsics. "
    "With --mocap the attitudes are the marker's turned by the calibration's T_marker_imu "
    "(needs a calibrate result); without, the IMU must rest at --segment-start and "
    "--segment-end and the accelerometer gives roll and pitch there.",
    epilog="Examples: mocap-calib drift --imu imu0/data.csv --calibration calib.yaml "
    "--segment-start 60 --segment-end 120 --mocap vicon0/data.csv | mocap-calib drift --imu mp2 "
    "--calibration intrinsics.yaml --segment-start 35 --segment-end 95",
)
