"""``mocap-calib simulate``: write a simulated session with known truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.main import app
from mocap_calib.workflows.simulate import effects_doc, simulate_to_folder

_EFFECTS_DOC = effects_doc()


@app.command(
    help="Simulate a mocap session (or a multi-position / static IMU log) with known truth.\n\n"
    "Writes OUT_DIR/mav0/imu0/data.csv, OUT_DIR/mav0/vicon0/data.csv (EuRoC layout) and "
    "OUT_DIR/truth.yaml (the calibration-result keys plus the injected effects and noise). "
    "The same seed gives the same bytes.",
    epilog="Examples: mocap-calib simulate sim_out --seed 7 --effect time_offset=0.012 "
    "--effect gyro_scale_misalignment | mocap-calib simulate mp --protocol multipos --counts "
    "--effect gyro_g_sensitivity",
)
def simulate(
    out_dir: Annotated[Path, typer.Argument(help="Folder to write the session into.")],
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same output).")] = 0,
    duration: Annotated[float, typer.Option(help="Session length in seconds.")] = 90.0,
    imu_rate: Annotated[float, typer.Option(help="IMU rate in Hz.")] = 200.0,
    mocap_rate: Annotated[float, typer.Option(help="Mocap rate in Hz.")] = 100.0,
    effect: Annotated[list[str] | None, typer.Option(
        "--effect", "-e", metavar="NAME[=VALUE]",
        help="Inject an effect (repeatable). Without a value a realistic magnitude is drawn. "
        + _EFFECTS_DOC)] = None,
    mocap_noise_corr: Annotated[float, typer.Option(
        help="Mocap noise correlated over this time constant in s (AR(1) with the same "
        "per-sample sigma), as real mocap noise is; 0: white.")] = 0.0,
    protocol: Annotated[str, typer.Option(
        help="flight: a drone flight in a mocap room; multipos: static orientations for "
        "'mocap-calib multipos' (no mocap); static: a still IMU for 'mocap-calib allan'.")]
    = "flight",
    counts: Annotated[bool, typer.Option(
        "--counts", help="With --protocol multipos: write raw counts of a 16-bit MEMS part "
        "(+-8 g, +-2000 deg/s; truth.yaml gives the nominal scales) for 'multipos --raw'.")]
    = False,
    motion: Annotated[str, typer.Option(
        help="With --protocol flight: flight (rotates about all axes), turntable (one "
        "vertical axis), planar (a ground robot: yaw and planar translation) or slow "
        "(low excitation). The last three cannot determine everything.")] = "flight",
    max_motion_hz: Annotated[float, typer.Option(
        help="With --motion flight: add motion from 1 Hz up to this (1-20 Hz, at most a fifth "
        "of the mocap rate), as a vibrating or aggressive flight has; 0: off.")] = 0.0,
) -> None:
    written = simulate_to_folder(out_dir, protocol=protocol, seed=seed, duration=duration,
                                 imu_rate=imu_rate, mocap_rate=mocap_rate, effects=effect or [],
                                 mocap_noise_corr=mocap_noise_corr, counts=counts,
                                 motion=motion, max_motion_hz=max_motion_hz)
    for path, what in written:
        typer.echo(f"wrote {path}  ({what})")
