"""``mocap-calib export``: write a calibration as another tool's configuration."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.main import app
from mocap_calib.workflows.export import FILE_NAMES, TARGETS, export_to_file

_TARGETS_HELP = ", ".join(f"{t} ({FILE_NAMES[t]})" for t in TARGETS)


@app.command(
    help="Export a calibration result to another tool's configuration, in that tool's frames "
    "and time-offset sign (docs/exports.md). Targets: " + _TARGETS_HELP + ".",
    epilog="Example: mocap-calib export calib.yaml --to openvins --out kalibr_imu_chain.yaml "
    "--noise noise.yaml",
)
def export(
    calibration: Annotated[Path, typer.Argument(help="Result YAML of 'mocap-calib calibrate'.")],
    to: Annotated[str, typer.Option("--to", help="Target tool: " + ", ".join(TARGETS) + ".")],
    out: Annotated[Path | None, typer.Option(
        help="File to write (default: the tool's own file name).", show_default=False)] = None,
    noise: Annotated[Path | None, typer.Option(
        help="Noise YAML (Kalibr keys, e.g. from 'mocap-calib allan'); default: the noise "
        "model the calibration used.", show_default=False)] = None,
    imu_rate: Annotated[float | None, typer.Option(
        help="IMU rate in Hz (default: the one measured by the calibration).",
        show_default=False)] = None,
    imu_topic: Annotated[str, typer.Option(
        help="IMU topic for the targets that name it.")] = "/imu0",
) -> None:
    exported, path = export_to_file(calibration, to, out, noise, imu_rate, imu_topic)
    for note in exported.notes:
        typer.echo(f"note: {note}")
    typer.echo(f"wrote {path}  ({to})")
