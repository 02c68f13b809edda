"""One session of a batch: the ``calibrate`` request it was given, and the function a worker
runs on it (the same workflow call as ``mocap-calib calibrate``, without writing files)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.priors import priors_from_results
from mocap_calib.errors import ConvergenceError
from mocap_calib.io.yaml_io import non_finite
from mocap_calib.workflows.calibrate import CalibrateRequest, run_calibration

#: ``calibrate`` options that make no sense per session in a batch, and what to do instead.
REFUSED = {
    "out": "each result goes to OUT/<id>/calib.yaml",
    "rrd": "run 'mocap-calib calibrate --rrd' on that session alone",
    "report": "the batch writes OUT/batch.yaml and the fleet summary",
    "quiet": "use 'mocap-calib batch --quiet'",
    "html": "pass --html to 'mocap-calib batch': OUT/batch.html shows every session",
}


@dataclass(frozen=True)
class SessionJob:
    """What a worker needs: the request, and (``--prior-from-history``) the earlier results of
    the same IMU as plain data with their session time set to their manifest date, and their
    files (which the priors name)."""

    id: str
    request: CalibrateRequest
    history: tuple[dict[str, Any], ...] = field(default_factory=tuple)
    at_ns: int | None = None
    history_files: tuple[str, ...] = ()


def history_priors(history: tuple[dict[str, Any], ...], at_ns: int | None,
                   files: tuple[str, ...] = ()) -> list:
    """Priors from the earlier results of the same IMU (a trend from two dates or more), as
    ``--prior`` gives them, each naming the ``files`` it comes from."""
    if not history:
        return []
    results = [CalibrationResult.from_dict(d) for d in history]
    times = {r.session.get("imu_start_ns") for r in results}
    if len(times) < 2:  # all from one date: no trend, the latest one stands for them
        results, files = results[-1:], files[-1:]
        at_ns = None
    return [replace(p, sources=files) for p in priors_from_results(results, at_ns)]


def run_session(job: SessionJob) -> CalibrationResult:
    """The worker's function: calibrate, drop what is only for inspection, return the result."""
    priors = history_priors(job.history, job.at_ns, job.history_files)
    result, _ = run_calibration(job.request, extra_priors=priors)
    result = replace(result, diagnostics=None)  # residual series: not in the result file
    bad = non_finite(result.to_dict())
    if bad:  # refused here, so the session fails with the reason (save_result refuses too)
        raise ConvergenceError(f"{bad}, not a number a calibration can have (no trustworthy "
                               "solution)")
    return result
