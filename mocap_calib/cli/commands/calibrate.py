"""``mocap-calib calibrate``: IMU biases, IMU-to-marker pose, gravity tilt, clock offset."""

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
from mocap_calib.workflows.calibrate import (
    CalibrateOutputs,
    InputSpec,
    calibrate_to_files,
    calibration_options,
    effects_help,
    noise_overrides,
)
from mocap_calib.workflows.session import GRAVITY

_EFFECTS_HELP = effects_help()


@app.command(
    help="Calibrate the IMU against mocap poses: gyro/accel bias, T_MI (IMU-to-marker), the "
    "mocap world's tilt against gravity and the clock offset, each with 1-sigma.",
    epilog="Examples: mocap-calib calibrate sim_out --out calib.yaml | mocap-calib calibrate "
    "--imu imu0/data.csv --mocap vicon0/data.csv --out calib.yaml --rrd calib.rrd",
)
def calibrate(
    mav0: MAV0 = None,
    imu: IMU = None,
    mocap: MOCAP = None,
    out: Annotated[Path, typer.Option(help="Result YAML to write.")] = Path("calib.yaml"),
    rrd: Annotated[Path | None, typer.Option(
        help="Also write a rerun recording of residuals and trajectories.",
        show_default=False)] = None,
    report: Annotated[Path | None, typer.Option(
        help="Also write the summary (estimates, 1-sigma, stage figures, notes) as a text "
        "report.", show_default=False)] = None,
    html: HTML = None,
    model: Annotated[str, typer.Option(
        help="Measurement model: base plus effects joined by '+', e.g. "
        "base+time_offset+gyro_scale_misalignment. Effects: " + _EFFECTS_HELP)]
    = "base+time_offset",
    gravity: Annotated[float, typer.Option(help="Assumed |g| in m/s^2.")] = GRAVITY,
    noise: Annotated[Path | None, typer.Option(
        help="Noise model YAML (Kalibr imu.yaml keys, e.g. from 'mocap-calib allan'). Default: "
        "the mav0's imu0/sensor.yaml, else EuRoC ADIS16448 values.", show_default=False)] = None,
    gyro_noise: Annotated[float | None, typer.Option(
        help="Gyro noise density, rad/s/sqrt(Hz).", show_default=False)] = None,
    gyro_walk: Annotated[float | None, typer.Option(
        help="Gyro bias random walk, rad/s^2/sqrt(Hz).", show_default=False)] = None,
    accel_noise: Annotated[float | None, typer.Option(
        help="Accel noise density, m/s^2/sqrt(Hz).", show_default=False)] = None,
    accel_walk: Annotated[float | None, typer.Option(
        help="Accel bias random walk, m/s^3/sqrt(Hz).", show_default=False)] = None,
    mocap_noise_mm: Annotated[float | None, typer.Option(
        help="Mocap position noise per axis, mm (default 0.5).", show_default=False)] = None,
    mocap_noise_deg: Annotated[float | None, typer.Option(
        help="Mocap attitude noise per axis, deg (default 0.05).", show_default=False)] = None,
    keyframe_spacing: Annotated[float, typer.Option(
        help="Keyframe spacing of the attitude and velocity factors, s.")] = 0.5,
    window: Annotated[float, typer.Option(help="Length of the position-factor windows, s.")] = 5.0,
    time_offset: Annotated[float | None, typer.Option(
        help="Known clock offset t_d in s (IMU stamp t happened at mocap time t + t_d); with "
        "time_offset in the model it only replaces the coarse search.", show_default=False)] = None,
    prior: Annotated[list[Path] | None, typer.Option(
        help="Earlier result YAML as a prior (repeatable; two or more give a trend).",
        show_default=False)] = None,
    start: Annotated[float | None, typer.Option(
        help="Use the session from this many seconds after the IMU start.",
        show_default=False)] = None,
    end: Annotated[float | None, typer.Option(
        help="Use the session up to this many seconds after the IMU start.",
        show_default=False)] = None,
    max_iterations: Annotated[int, typer.Option(
        help="Most Levenberg-Marquardt iterations per solve (a solve still improving at the "
        "limit is retried once from where it stopped; then the command exits 4).")] = 30,
    max_offset: Annotated[float | None, typer.Option(
        help="Search the clock offset only within +-this many seconds of the raw stamps.",
        show_default=False)] = None,
    segments: Annotated[int, typer.Option(
        help="Calibrate this many time segments on their own and compare them (consistency; "
        "0: skip).")] = 3,
    accept_implausible: Annotated[bool, typer.Option(
        "--accept-implausible", help="Write an answer that fails the plausibility checks "
        "(marked as such) instead of exiting 4.")] = False,
    plausible: Annotated[Path | None, typer.Option(
        help="YAML file overriding the plausibility limits (see docs/diagnosis.md).",
        show_default=False)] = None,
    no_robust: Annotated[bool, typer.Option(
        "--no-robust", help="Do not down-weight mocap outliers.")] = False,
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
    opts = calibration_options(model=model, gravity=gravity, keyframe_spacing=keyframe_spacing,
                               window=window, time_offset=time_offset, robust=not no_robust,
                               start=start, end=end, max_iterations=max_iterations,
                               max_offset=max_offset, segments=segments,
                               accept_implausible=accept_implausible, plausible=plausible)
    overrides = noise_overrides(gyro_noise=gyro_noise, gyro_walk=gyro_walk,
                                accel_noise=accel_noise, accel_walk=accel_walk,
                                mocap_noise_mm=mocap_noise_mm, mocap_noise_deg=mocap_noise_deg)
    run = calibrate_to_files(spec, opts, CalibrateOutputs(out, report, rrd, html), noise, overrides,
                             prior or [], Progress(quiet))
    typer.echo(run.summary)
    typer.echo("")
    for line in run.written:
        typer.echo(line)
