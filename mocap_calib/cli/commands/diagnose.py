"""``mocap-calib diagnose``: find what the calibrated model misses, name it, add it."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.common import Progress
from mocap_calib.cli.main import app
from mocap_calib.workflows.diagnose import NOT_OPTIONS, DiagnoseRequest, diagnose_to_files


def _diagnose(request: DiagnoseRequest) -> None:
    run = diagnose_to_files(request, Progress(request.outputs.quiet))
    typer.echo(run.summary)
    typer.echo("")
    for line in run.written:
        typer.echo(line)


add_command(
    app, "diagnose", DiagnoseRequest, _diagnose, exclude=NOT_OPTIONS,
    help="Diagnose the measurement model: calibrate the starting model, predict what the IMU "
    "should have measured from the mocap, find where prediction and measurement disagree, name "
    "the missing effect (likelihood-ratio test over the canonical effects), add it and repeat "
    "until nothing significant is left ('none' when nothing is missing).",
    epilog="Example: mocap-calib diagnose sim_out --out report.yaml --rrd report.rrd",
)
