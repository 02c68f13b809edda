"""``mocap-calib allan``: IMU noise model (Kalibr imu.yaml) from a long static log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.common import (
    ACCEL_UNIT,
    COLUMNS,
    GYRO_UNIT,
    HTML,
    IMU,
    IMU_TOPIC,
    STAMP,
    TIME_UNIT,
    Progress,
)
from mocap_calib.cli.main import app


@app.command(
    help="Characterise IMU noise from a long static log by overlapping Allan deviation: white "
    "noise density N, rate random walk K and bias instability B per axis.\n\n"
    "Writes Kalibr imu.yaml keys (gyroscope_noise_density, gyroscope_random_walk, "
    "accelerometer_noise_density, accelerometer_random_walk), bias instability per axis, the "
    "per-axis values and the curves; the file is accepted by 'mocap-calib calibrate --noise'. "
    "Record 2-4 h (or more) with the IMU resting still.",
    epilog="Examples: mocap-calib allan --imu static/mav0/imu0/data.csv --out noise.yaml "
    "--rrd allan.rrd | mocap-calib calibrate sim_out --noise noise.yaml",
)
def allan(
    imu: IMU = None,
    out: Annotated[Path, typer.Option(help="Noise YAML to write.")] = Path("noise.yaml"),
    rrd: Annotated[Path | None, typer.Option(
        help="Also write a rerun recording of the Allan deviation curves and fitted lines "
        "(log-log; x: 1000 log10(tau/s)).", show_default=False)] = None,
    aggregate: Annotated[str, typer.Option(
        help="How the Kalibr keys combine the three axes: mean or max (conservative).")]
    = "mean",
    tau_min: Annotated[float | None, typer.Option(
        help="Shortest averaging time fitted, s (raise it when the IMU's low-pass filter bends "
        "the curve at short tau).", show_default=False)] = None,
    allow_unresolved: Annotated[bool, typer.Option(
        "--allow-unresolved", help="Write the result even if the log is too short to resolve "
        "the random walks (written as null; calibrate then keeps its defaults for them).")]
    = False,
    html: HTML = None,
    columns: COLUMNS = None,
    time_unit: TIME_UNIT = None,
    gyro_unit: GYRO_UNIT = None,
    accel_unit: ACCEL_UNIT = None,
    imu_topic: IMU_TOPIC = None,
    stamp: STAMP = "header",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress lines.")] = False,
) -> None:
    from mocap_calib.workflows.imu.allan import run_allan
    from mocap_calib.workflows.imu.imu_input import ImuSpec

    spec = ImuSpec(imu, columns, time_unit, gyro_unit, accel_unit, imu_topic, stamp)
    run = run_allan(spec, out=out, rrd=rrd,
                    aggregate=aggregate, tau_min_s=tau_min,
                    require_random_walk=not allow_unresolved, progress=Progress(quiet),
                    html=html)
    typer.echo(run.summary())
    typer.echo(f"\nwrote {out}")
    if html is not None:
        typer.echo(f"wrote {html}")
    if rrd is not None:
        typer.echo(f"wrote {run.written[-1]}  (open with: mocap-calib view {run.written[-1]})")
