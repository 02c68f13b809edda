"""``mocap-calib export``: a result in another tool's format."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.main import app


@app.command(
    help="Write a result in another tool's format. --to imu_tk: multipos intrinsics as "
    "imu_tk's calibration files OUT_acc.calib and OUT_gyro.calib (misalignment T, scale K, "
    "bias b: calibrated = T K (raw - b)).",
    epilog="Example: mocap-calib multipos --raw --imu raw.csv --columns 't=0,accel=1:4,"
    "gyro=4:7' --out intrinsics.yaml && mocap-calib export intrinsics.yaml --to imu_tk "
    "--out imu",
)
def export(
    result: Annotated[Path, typer.Argument(help="Result YAML (multipos intrinsics).")],
    to: Annotated[str, typer.Option(help="Target format: imu_tk.")],
    out: Annotated[Path, typer.Option(help="Output prefix (imu_tk: PREFIX_acc.calib, "
                                      "PREFIX_gyro.calib).")],
) -> None:
    from mocap_calib.workflows.intrinsics_export import export_intrinsics

    typer.echo(export_intrinsics(result, to, out).summary())
