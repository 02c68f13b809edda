"""``mocap-calib batch``: calibrate every session of a manifest, locally or on Dask."""

from __future__ import annotations

import typer

from mocap_calib.batch.manifest import ManifestError
from mocap_calib.batch.progress import ProgressBar
from mocap_calib.batch.runner import BatchRequest, run_batch
from mocap_calib.cli.build import add_command
from mocap_calib.cli.main import app
from mocap_calib.errors import CalibrationError, InputError, Interrupted


def _batch(request: BatchRequest) -> None:
    out = request.out
    try:
        report = run_batch(request.manifest, out, engine=request.engine,
                           workers=request.workers, scheduler=request.scheduler,
                           prior_from_history=request.prior_from_history, html=request.html,
                           progress=ProgressBar(quiet=request.quiet))
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


add_command(
    app, "batch", BatchRequest, _batch,
    help="Calibrate many sessions listed in a YAML manifest (sessions: id, imu_id, date, imu, "
    "mocap or mav0, and any calibrate option with underscores, e.g. rigid_body). Results go to "
    "OUT/<id>/calib.yaml, finished sessions are skipped on a rerun, a failing session does "
    "not stop the others; OUT/fleet/ holds the history and trends per imu_id.",
    epilog="Examples: mocap-calib batch fleet.yaml --out results | mocap-calib batch "
    "fleet.yaml --out results --engine dask --scheduler tcp://10.0.0.5:8786",
)
