"""``mocap-calib allan``: IMU noise model (Kalibr imu.yaml) from a long static log."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.common import Progress
from mocap_calib.cli.main import app
from mocap_calib.workflows.imu.allan import AllanRequest, run_allan
from mocap_calib.workflows.imu.imu_input import MULTIPOS_ONLY


def _allan(request: AllanRequest) -> None:
    run = run_allan(request, progress=Progress(request.quiet))
    typer.echo(run.summary())
    typer.echo(f"\nwrote {request.out}")
    if request.html is not None:
        typer.echo(f"wrote {request.html}")
    if request.rrd is not None:
        typer.echo(f"wrote {run.written[-1]}  (open with: mocap-calib view {run.written[-1]})")


add_command(
    app, "allan", AllanRequest, _allan, exclude=MULTIPOS_ONLY,
    help="Characterise IMU noise from a long static log by overlapping Allan deviation: white "
    "noise density N, rate random walk K and bias instability B per axis.\n\n"
    "Writes Kalibr imu.yaml keys (gyroscope_noise_density, gyroscope_random_walk, "
    "accelerometer_noise_density, accelerometer_random_walk), bias instability per axis, the "
    "per-axis values and the curves; the file is accepted by 'mocap-calib calibrate --noise'. "
    "Record 2-4 h (or more) with the IMU resting still.",
    epilog="Examples: mocap-calib allan --imu static/mav0/imu0/data.csv --out noise.yaml "
    "--rrd allan.rrd | mocap-calib calibrate sim_out --noise noise.yaml",
)
