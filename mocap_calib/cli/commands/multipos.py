"""``mocap-calib multipos``: IMU intrinsics from a multi-position session (no mocap)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.common import ACCEL_UNIT, COLUMNS, GYRO_UNIT, IMU, TIME_UNIT, Progress
from mocap_calib.cli.main import app


@app.command(
    help="Calibrate accelerometer and gyroscope intrinsics without mocap (Tedaldi et al. 2014): "
    "scale errors, misalignments and biases, each with 1-sigma, from a session that starts at "
    "rest (--init-static s) and then holds the IMU still in 36-50 orientations for 2-4 s each.\n\n"
    "Writes accel_matrix, accel_bias, gyro_matrix, gyro_bias (a_m = M_a f + b_a, "
    "w_m = M_g w + b_g; docs/conventions.md) with sigma, residuals and diagnostics.",
    epilog="Examples: mocap-calib simulate mp --protocol multipos && mocap-calib multipos --imu "
    "mp --out intrinsics.yaml | mocap-calib multipos --imu imu.csv --prior jan.yaml --prior "
    "mar.yaml --out may.yaml",
)
def multipos(
    imu: IMU = None,
    out: Annotated[Path, typer.Option(help="Intrinsics YAML to write.")] = Path(
        "intrinsics.yaml"),
    prior: Annotated[list[Path] | None, typer.Option(
        help="Earlier intrinsics YAML from 'mocap-calib multipos' as a prior (repeatable; two "
        "or more give a first-order trend extrapolated to this session's time).",
        show_default=False)] = None,
    prior_biases: Annotated[bool, typer.Option(
        "--prior-biases", help="Let the prior constrain the biases too (default: only the "
        "matrices; turn-on biases change between power-ups).")] = False,
    prior_sigma_scale: Annotated[float, typer.Option(
        help="Multiply the prior's sigmas by this (> 1 allows for change since then).")] = 1.0,
    init_static: Annotated[float, typer.Option(
        help="Length of the initial rest period, s (30-50 recommended).")] = 30.0,
    window: Annotated[float, typer.Option(help="Static-detector window, s.")] = 1.0,
    min_interval: Annotated[float, typer.Option(
        help="Shortest static interval used, s.")] = 0.5,
    min_orientations: Annotated[int, typer.Option(
        help="Fewest distinct static orientations accepted.")] = 9,
    gravity: Annotated[float, typer.Option(help="Local |g| in m/s^2.")] = 9.81,
    columns: COLUMNS = None,
    time_unit: TIME_UNIT = None,
    gyro_unit: GYRO_UNIT = None,
    accel_unit: ACCEL_UNIT = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress lines.")] = False,
) -> None:
    from mocap_calib.workflows.imu_input import ImuSpec
    from mocap_calib.workflows.multipos import run_multipos

    run = run_multipos(
        ImuSpec(imu, columns, time_unit, gyro_unit, accel_unit), out=out,
        init_static_s=init_static, window_s=window, min_interval_s=min_interval,
        gravity=gravity, min_orientations=min_orientations, prior_files=prior or [],
        prior_biases=prior_biases, prior_sigma_scale=prior_sigma_scale,
        progress=Progress(quiet))
    typer.echo(run.summary())
    typer.echo(f"\nwrote {out}")
