"""``mocap-calib multipos``: IMU intrinsics from a multi-position session (no mocap)."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.common import Progress
from mocap_calib.cli.main import app
from mocap_calib.workflows.imu.multipos import MultiposRequest, run_multipos


def _multipos(request: MultiposRequest) -> None:
    run = run_multipos(request, progress=Progress(request.quiet))
    typer.echo(run.summary())
    typer.echo(f"\nwrote {request.out}")
    if request.html is not None:
        typer.echo(f"wrote {request.html}")


add_command(
    app, "multipos", MultiposRequest, _multipos,
    help="Calibrate accelerometer and gyroscope intrinsics without mocap (Tedaldi et al. 2014, "
    "as imu_tk): scale factors, misalignments and biases, each with 1-sigma, and the gyro's "
    "g-sensitivity when the data show it, from a session that starts at rest (--init-static "
    "s) and then holds the IMU still in 36-50 orientations for 2-4 s each.\n\n"
    "Writes accel_matrix, accel_bias, gyro_matrix, gyro_bias (a_m = M_a f + b_a, "
    "w_m = M_g w + G f + b_g; docs/conventions.md) with sigma, residuals, diagnostics and "
    "imu_tk's T K (raw - b) form. --raw takes the readings as raw sensor counts (the units "
    "are found; --accel-scale etc. only set the starting point). Quality figures (chi2, "
    "poorly determined) are in calibrated units, so they do not depend on the input's.",
    epilog="Examples: mocap-calib simulate mp --protocol multipos && mocap-calib multipos --imu "
    "mp --out intrinsics.yaml | mocap-calib multipos --raw --accel acc.txt --gyro gyro.txt "
    "--out raw.yaml && mocap-calib export raw.yaml --to imu_tk --out imu | mocap-calib "
    "multipos --imu imu.csv --prior jan.yaml --prior mar.yaml --out may.yaml",
)
