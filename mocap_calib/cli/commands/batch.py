"""``mocap-calib batch``: calibrate every session of a manifest, locally or on Dask."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mocap_calib.cli.main import app


@app.command(
    help="Calibrate many sessions listed in a YAML manifest (sessions: id, imu_id, date, imu, "
    "mocap or mav0, and any calibrate option with underscores, e.g. rigid_body). Results go to "
    "OUT/<id>/calib.yaml, finished sessions are skipped on a rerun, a failing session does "
    "not stop the others; OUT/fleet/ holds the history and trends per imu_id.",
    epilog="Examples: mocap-calib batch fleet.yaml --out results | mocap-calib batch "
    "fleet.yaml --out results --engine dask --scheduler tcp://10.0.0.5:8786",
)
def batch(
    manifest: Annotated[Path, typer.Argument(help="Manifest YAML listing the sessions.")],
    out: Annotated[Path, typer.Option(help="Output folder (one subfolder per session).")],
    engine: Annotated[str, typer.Option(
        help="local (a process pool on this machine) or dask (needs "
        "pip install 'mocap-calib\\[cluster]').")] = "local",
    scheduler: Annotated[str | None, typer.Option(
        help="With --engine dask: address of a running Dask scheduler (default: a local "
        "cluster).", show_default=False)] = None,
    workers: Annotated[int | None, typer.Option(
        help="Worker processes (default: the number of cores; with --scheduler, the "
        "cluster's).", show_default=False)] = None,
    prior_from_history: Annotated[bool, typer.Option(
        "--prior-from-history", help="Calibrate each session with the earlier sessions of the "
        "same imu_id as priors (a trend from two dates on).")] = False,
    html: Annotated[bool, typer.Option("--html", help="Also write OUT/batch.html.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    from mocap_calib.batch.manifest import ManifestError
    from mocap_calib.batch.progress import ProgressBar
    from mocap_calib.batch.runner import run_batch
    from mocap_calib.errors import CalibrationError, InputError, Interrupted

    try:
        report = run_batch(manifest, out, engine=engine, workers=workers, scheduler=scheduler,
                           prior_from_history=prior_from_history, html=html,
                           progress=ProgressBar(quiet=quiet))
    except ManifestError as err:  # one line each; main() prints the last and sets the code
        for line in err.problems[:-1]:
            typer.echo(f"error: {line}", err=True)
        raise InputError(err.problems[-1]) from None
    except Interrupted as err:  # finished sessions are kept: say so, not "nothing written"
        err.args = (f"{str(err).split(';')[0]}; the finished sessions are in {out}; the same "
                    "command finishes the rest",)
        raise
    counts = {k: sum(s.status == k for s in report.sessions) for k in ("ok", "skipped", "failed")}
    typer.echo(f"{len(report.sessions)} sessions: {counts['ok']} calibrated, "
               f"{counts['skipped']} unchanged since the last run, {counts['failed']} failed")
    for s in report.failed:
        typer.echo(f"  {s.id}: {s.error}")
    for o in report.outliers:
        typer.echo(f"outlier: {o['id']} ({o['imu_id']}, {o['date']}): {o['block']} is "
                   f"{o['z']:.1f} sigma from the rest of its history")
    for path in report.files:
        typer.echo(f"wrote {path}")
    if report.failed:
        raise CalibrationError(f"{len(report.failed)} of {len(report.sessions)} sessions "
                               f"failed; see {report.out_dir / 'batch.yaml'}")
