"""``mocap-calib export``: write a calibration as another tool's configuration."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.main import app
from mocap_calib.workflows.export import ALL_TARGETS, FILE_NAMES, TARGETS, export_result

_TARGETS_HELP = ", ".join(f"{t} ({FILE_NAMES[t]})" for t in TARGETS) + (
    "; imu_tk (multipos intrinsics: OUT_acc.calib and OUT_gyro.calib, T K (raw - b))")


@app.command(
    help="Export a calibration result to another tool's configuration, in that tool's frames "
    "and time-offset sign (docs/exports.md). Targets: " + _TARGETS_HELP + ".",
    epilog="Examples: mocap-calib export calib.yaml --to openvins --out kalibr_imu_chain.yaml "
    "--noise noise.yaml | mocap-calib export intrinsics.yaml --to imu_tk --out imu",
)
def export(
    calibration: Annotated[Path, typer.Argument(
        help="Result YAML of 'mocap-calib calibrate' (for --to imu_tk: intrinsics of "
        "'mocap-calib multipos').")],
    to: Annotated[str, typer.Option("--to", help="Target tool: " + ", ".join(ALL_TARGETS)
                                    + ".")],
    out: Annotated[Path | None, typer.Option(
        help="File to write (default: the tool's own file name); imu_tk: the prefix of its "
        "two files (default 'imu').", show_default=False)] = None,
    noise: Annotated[Path | None, typer.Option(
        help="Noise YAML (Kalibr keys, e.g. from 'mocap-calib allan'); default: the noise "
        "model the calibration used.", show_default=False)] = None,
    imu_rate: Annotated[float | None, typer.Option(
        help="IMU rate in Hz (default: the one measured by the calibration).",
        show_default=False)] = None,
    imu_topic: Annotated[str, typer.Option(
        help="IMU topic for the targets that name it.")] = "/imu0",
) -> None:
    for line in export_result(calibration, to, out, noise, imu_rate, imu_topic):
        typer.echo(line)
