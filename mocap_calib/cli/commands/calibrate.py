"""``mocap-calib calibrate``: IMU biases, IMU-to-marker pose, gravity tilt, clock offset."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.common import Progress
from mocap_calib.cli.main import app
from mocap_calib.workflows.calibrate import CalibrateRequest, calibrate_to_files


def _calibrate(request: CalibrateRequest) -> None:
    run = calibrate_to_files(request, Progress(request.outputs.quiet))
    typer.echo(run.summary)
    typer.echo("")
    for line in run.written:
        typer.echo(line)


add_command(
    app, "calibrate", CalibrateRequest, _calibrate,
    help="Calibrate the IMU against mocap poses: gyro/accel bias, T_MI (IMU-to-marker), the "
    "mocap world's tilt against gravity and the clock offset, each with 1-sigma.",
    epilog="Examples: mocap-calib calibrate sim_out --out calib.yaml | mocap-calib calibrate "
    "--imu imu0/data.csv --mocap vicon0/data.csv --out calib.yaml --rrd calib.rrd",
)
