"""``mocap-calib export``: write a calibration as another tool's configuration."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.main import app
from mocap_calib.workflows.export import TARGETS_HELP, ExportRequest, export_request


def _export(request: ExportRequest) -> None:
    for line in export_request(request):
        typer.echo(line)


add_command(
    app, "export", ExportRequest, _export,
    help="Export a calibration result to another tool's configuration, in that tool's frames "
    "and time-offset sign (docs/exports.md). Targets: " + TARGETS_HELP + ".",
    epilog="Examples: mocap-calib export calib.yaml --to openvins --out kalibr_imu_chain.yaml "
    "--noise noise.yaml | mocap-calib export intrinsics.yaml --to imu_tk --out imu",
)
