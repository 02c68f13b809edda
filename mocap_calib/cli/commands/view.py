"""``mocap-calib view``: open a rerun recording (``calibrate --rrd``) in the rerun viewer."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.main import app
from mocap_calib.workflows.view import open_recording


@app.command(
    help="Open a rerun recording written by 'calibrate --rrd' in the rerun viewer. Without a "
    "display (or without the viewer) print how to open it elsewhere.",
    epilog="Example: mocap-calib view calib.rrd",
)
def view(
    recording: Annotated[Path, typer.Argument(help="The .rrd file to open.",
                                              show_default=False)],
) -> None:
    message = open_recording(recording)
    if message:
        typer.echo(message)
