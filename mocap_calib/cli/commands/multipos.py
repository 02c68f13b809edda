"""``mocap-calib multipos``: IMU intrinsics from a multi-position session (no mocap)."""

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
from mocap_calib.workflows.session import GRAVITY


@app.command(
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
def multipos(
    imu: IMU = None,
    out: Annotated[Path, typer.Option(help="Intrinsics YAML to write.")] = Path(
        "intrinsics.yaml"),
    raw: Annotated[bool, typer.Option(
        "--raw", help="The readings are raw sensor counts (e.g. a 16-bit MEMS part's "
        "registers); results in SI units and in imu_tk's form.")] = False,
    accel: Annotated[Path | None, typer.Option(
        "--accel", help="imu_tk's accelerometer file ('t ax ay az' per line, stamps in s "
        "unless --time-unit), with --gyro instead of --imu.", show_default=False)] = None,
    gyro: Annotated[Path | None, typer.Option(
        "--gyro", help="imu_tk's gyroscope file ('t gx gy gz' per line).",
        show_default=False)] = None,
    accel_scale: Annotated[str | None, typer.Option(
        help="With --raw: nominal accelerometer scale, m/s^2 per count (1 or 3 values, e.g. "
        "0.0023942 for 4096 LSB/g). Only the starting point; default: found from the data.",
        show_default=False)] = None,
    accel_offset: Annotated[str | None, typer.Option(
        help="With --raw: nominal accelerometer offset, counts (1 or 3 values; e.g. 32768 "
        "for unsigned output).", show_default=False)] = None,
    gyro_scale: Annotated[str | None, typer.Option(
        help="With --raw: nominal gyro scale, rad/s per count (1 or 3 values).",
        show_default=False)] = None,
    gyro_offset: Annotated[str | None, typer.Option(
        help="With --raw: nominal gyro offset, counts.", show_default=False)] = None,
    g_sensitivity: Annotated[str, typer.Option(
        help="The gyro's g-sensitivity G (w_m = M_g w + G f + b_g): auto (kept if a "
        "likelihood-ratio test on the static poses says so), on or off.")] = "auto",
    threshold: Annotated[list[float] | None, typer.Option(
        help="Static-detector threshold multiple k to try (repeatable; default 2..10): static "
        "where |var_w(a)| < k |var_init(a)|, imu_tk's meaning.", show_default=False)] = None,
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
    gravity: Annotated[float, typer.Option(help="Local |g| in m/s^2.")] = GRAVITY,
    html: HTML = None,
    columns: COLUMNS = None,
    time_unit: TIME_UNIT = None,
    gyro_unit: GYRO_UNIT = None,
    accel_unit: ACCEL_UNIT = None,
    imu_topic: IMU_TOPIC = None,
    stamp: STAMP = "header",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress lines.")] = False,
) -> None:
    from mocap_calib.workflows.imu.imu_input import ImuSpec
    from mocap_calib.workflows.imu.multipos import MultiposOptions, run_multipos

    options = MultiposOptions(
        init_static_s=init_static, window_s=window, min_interval_s=min_interval,
        gravity=gravity, min_orientations=min_orientations, thresholds=threshold or (),
        g_sensitivity=g_sensitivity, accel_scale=accel_scale, accel_offset=accel_offset,
        gyro_scale=gyro_scale, gyro_offset=gyro_offset, prior_files=prior or [],
        prior_biases=prior_biases, prior_sigma_scale=prior_sigma_scale)
    spec = ImuSpec(imu, columns, time_unit, gyro_unit, accel_unit, imu_topic, stamp, raw=raw,
                   accel=accel, gyro=gyro)
    run = run_multipos(spec, out=out, options=options, progress=Progress(quiet), html=html)
    typer.echo(run.summary())
    typer.echo(f"\nwrote {out}")
    if html is not None:
        typer.echo(f"wrote {html}")
