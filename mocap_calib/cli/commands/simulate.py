"""``mocap-calib simulate``: write a simulated session with known truth."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.main import app
from mocap_calib.workflows.simulate import SimulateRequest, simulate_request


def _simulate(request: SimulateRequest) -> None:
    for path, what in simulate_request(request):
        typer.echo(f"wrote {path}  ({what})")


add_command(
    app, "simulate", SimulateRequest, _simulate,
    help="Simulate a mocap session (or a multi-position / static IMU log) with known truth.\n\n"
    "Writes OUT_DIR/mav0/imu0/data.csv, OUT_DIR/mav0/vicon0/data.csv (EuRoC layout) and "
    "OUT_DIR/truth.yaml (the calibration-result keys plus the injected effects and noise). "
    "The same seed gives the same bytes.",
    epilog="Examples: mocap-calib simulate sim_out --seed 7 --effect time_offset=0.012 "
    "--effect gyro_scale_misalignment | mocap-calib simulate mp --protocol multipos --counts "
    "--effect gyro_g_sensitivity",
)
