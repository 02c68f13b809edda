"""``mocap-calib compile``: compile the numerical kernels into their cache (once, at install)."""

from __future__ import annotations

import typer

from mocap_calib.cli.build import add_command
from mocap_calib.cli.main import app
from mocap_calib.workflows.compile import CompileRequest, compile_kernels


def _compile(request: CompileRequest) -> None:
    for line in compile_kernels(request).lines():
        typer.echo(line)


add_command(
    app, "compile", CompileRequest, _compile,
    help="Compile the numerical kernels into their cache, so that no calibration has to "
    "(the first run after installing otherwise spends ~20 s on it). The install scripts run "
    "it; run it again after upgrading, or with NUMBA_CACHE_DIR set where the install is "
    "read-only.",
)
