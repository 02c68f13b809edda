"""``mocap-calib diagnose``: find what the calibrated model misses, name it, add it."""

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
from mocap_calib.workflows.diagnose import InputSpec, diagnose_options, diagnose_to_files
from mocap_calib.workflows.session import GRAVITY


@app.command(
    help="Diagnose the measurement model: calibrate the starting model, predict what the IMU "
    "should have measured from the mocap, find where prediction and measurement disagree, name "
    "the missing effect (likelihood-ratio test over the canonical effects), add it and repeat "
    "until nothing significant is left ('none' when nothing is missing).",
    epilog="Example: mocap-calib diagnose sim_out --out report.yaml --rrd report.rrd",
)
def diagnose(
    mav0: MAV0 = None,
    imu: IMU = None,
    mocap: MOCAP = None,
    out: Annotated[Path, typer.Option(help="Report YAML to write.")] = Path("report.yaml"),
    rrd: Annotated[Path | None, typer.Option(
        help="Also write a rerun recording with the residuals of every step.",
        show_default=False)] = None,
    html: HTML = None,
    start: Annotated[str, typer.Option(
        help="Starting model, e.g. base or base+time_offset.")] = "base",
    candidates: Annotated[str | None, typer.Option(
        help="Effects to try, joined by '+' (default: all canonical effects).",
        show_default=False)] = None,
    alpha: Annotated[float, typer.Option(
        help="False-alarm rate per step (Bonferroni-corrected over the candidates).")] = 0.01,
    max_steps: Annotated[int, typer.Option(help="Most effects to add.")] = 4,
    gravity: Annotated[float, typer.Option(help="Assumed |g| in m/s^2.")] = GRAVITY,
    noise: Annotated[Path | None, typer.Option(
        help="Noise model YAML (Kalibr imu.yaml keys).", show_default=False)] = None,
    window: Annotated[float, typer.Option(help="Length of the position-factor windows, s.")] = 5.0,
    plausible: Annotated[Path | None, typer.Option(
        help="YAML file overriding the plausible effect magnitudes (docs/diagnosis.md); an "
        "effect outside them is listed as implausible, never as found.",
        show_default=False)] = None,
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
    opts = diagnose_options(start=start, candidates=candidates, alpha=alpha,
                            max_steps=max_steps, gravity=gravity, window=window,
                            plausible=plausible)
    spec = InputSpec(mav0, imu, mocap, pose_source, columns, time_unit, gyro_unit, accel_unit,
                     quat_order, position_unit, imu_topic=imu_topic, mocap_topic=mocap_topic,
                     mocap_frame=mocap_frame, stamp=stamp, mocap_format=mocap_format,
                     rigid_body=rigid_body, rotation=rotation, mocap_rate=mocap_rate)
    run = diagnose_to_files(spec, opts, out, rrd, noise, Progress(quiet), html=html)
    typer.echo(run.summary)
    typer.echo("")
    for line in run.written:
        typer.echo(line)
