"""``mocap-calib groundtruth``: an IMU ground-truth trajectory for evaluating VIO."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.common import Progress
from mocap_calib.cli.main import app
from mocap_calib.workflows.groundtruth import GroundtruthRequest, run_groundtruth


def _groundtruth(request: GroundtruthRequest) -> None:
    run = run_groundtruth(request, progress=Progress(request.quiet))
    typer.echo(run.summary())
    typer.echo(f"wrote {run.trajectory}\nwrote {run.sidecar}  (how it was made)")


add_command(
    app, "groundtruth", GroundtruthRequest, _groundtruth,
    help="Write the IMU frame's trajectory (pose, velocity, biases) in a gravity-aligned world "
    "on the IMU clock, from the mocap and a calibration: an error-state Kalman filter and "
    "smoother fuse the calibrated IMU with the mocap, bridge short mocap gaps and leave out "
    "what is too uncertain. EuRoC state_groundtruth_estimate0 layout (or TUM), plus a YAML "
    "sidecar that says how it was made.",
    epilog="Example: mocap-calib groundtruth --imu flight.bag --mocap flight.bag --calibration "
    "calib.yaml --out gt.csv  (then: evo_ape euroc gt.csv vio.csv)",
)
