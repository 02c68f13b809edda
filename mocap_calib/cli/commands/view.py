"""``mocap-calib view``: open a rerun recording (``calibrate --rrd``) in the rerun viewer."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.main import app
from mocap_calib.workflows.view import ViewRequest, open_recording


def _view(request: ViewRequest) -> None:
    message = open_recording(request.recording)
    if message:
        typer.echo(message)


add_command(
    app, "view", ViewRequest, _view,
    help="Open a rerun recording written by 'calibrate --rrd' in the rerun viewer. Without a "
    "display (or without the viewer) print how to open it elsewhere.",
    epilog="Example: mocap-calib view calib.rrd",
)
