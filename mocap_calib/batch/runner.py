"""Calibrate every session of a manifest on an engine; skip what is finished; keep going past
failures; write each result atomically; then the fleet summary.

Layout of OUT:
    OUT/<id>/calib.yaml      each session's result (``session.batch`` holds its input hash)
    OUT/batch.yaml           status of every session: ok, skipped, failed (with its error)
    OUT/fleet/               history and trends per IMU (see :mod:`mocap_calib.batch.fleet`)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field
from pathlib import Path
from typing import Any

from mocap_calib.batch.engine import ENGINES, Engine, make_engine
from mocap_calib.batch.manifest import Manifest, SessionEntry, load_manifest
from mocap_calib.batch.session import SessionJob, run_session
from mocap_calib.batch.store import Digests, batch_id, finished_hash, input_hash
from mocap_calib.core import interrupt
from mocap_calib.core.params import param
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.versioned import header
from mocap_calib.errors import ConvergenceError, InputError
from mocap_calib.io.atomic import remove_leftovers
from mocap_calib.io.yaml_io import load_result, load_yaml, save_result, save_yaml
from mocap_calib.workflows.outputs import Named, OutputPlan, output

BATCH_KIND, BATCH_VERSION = "batch", 1
#: The fleet summary's files in OUT/fleet/ (:func:`mocap_calib.batch.fleet.write_fleet`).
FLEET_FILES = ("history.csv", "trends.csv", "fleet.yaml")


@dataclass
class SessionStatus:
    """Where one session stands; ``status`` is pending, ok, skipped (finished before, inputs
    unchanged) or failed (``error`` says why, in one line)."""

    id: str
    imu_id: str
    date: str
    status: str = "pending"
    error: str = ""
    seconds: float | None = None
    input_hash: str = ""
    priors_from: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"id": self.id, "imu_id": self.imu_id, "date": self.date,
                             "status": self.status}
        if self.status in ("ok", "skipped"):
            d["result"] = f"{self.id}/calib.yaml"
        if self.error:
            d["error"] = self.error
        if self.seconds is not None:
            d["seconds"] = round(self.seconds, 2)
        if self.priors_from:
            d["priors_from"] = list(self.priors_from)
        d["input_hash"] = self.input_hash
        return d


@dataclass
class BatchProgress:
    """What a progress bar shows."""

    total: int
    done: int = 0
    running: int = 0
    failed: int = 0
    skipped: int = 0
    eta_s: float | None = None
    last: str = ""


@dataclass
class BatchReport:
    out_dir: Path
    sessions: list[SessionStatus]
    files: list[Path] = field(default_factory=list)
    outliers: list[dict[str, Any]] = field(default_factory=list)  # see fleet.write_fleet

    @property
    def failed(self) -> list[SessionStatus]:
        return [s for s in self.sessions if s.status == "failed"]


ProgressCallback = Callable[[BatchProgress], None]


def _rounds(sessions: list[SessionEntry], prior_from_history: bool) -> list[list[int]]:
    """Indices in the order they can run: all at once, or (with priors from the history) by
    how many earlier dates the same IMU has, so each session's predecessors are done first."""
    if not prior_from_history:
        return [list(range(len(sessions)))]
    depth = [len({o.time_ns for o in sessions if o.imu_id == s.imu_id and o.time_ns < s.time_ns})
             for s in sessions]
    return [[i for i, d in enumerate(depth) if d == k] for k in range(max(depth) + 1)]


class _Batch:
    """State of one run: statuses, results in memory (for history), the engine once needed."""

    def __init__(self, manifest: Manifest, out_dir: Path, make: Callable[[], Engine],
                 prior_from_history: bool, progress: ProgressCallback | None) -> None:
        self.m = manifest
        self.out = out_dir
        self.make = make
        self.engine: Engine | None = None
        self.history = prior_from_history
        self.progress = progress
        self.status = [SessionStatus(s.id, s.imu_id, s.date) for s in manifest.sessions]
        self.results: dict[int, CalibrationResult] = {}
        self.digests = Digests()
        self.state = BatchProgress(len(manifest.sessions))
        self.t_first: float | None = None
        self.computed = 0

    def result_path(self, i: int) -> Path:
        return self.out / self.m.sessions[i].id / "calib.yaml"

    def predecessors(self, i: int) -> list[int]:
        s = self.m.sessions[i]
        if not self.history:
            return []
        return sorted((j for j, o in enumerate(self.m.sessions)
                       if o.imu_id == s.imu_id and o.time_ns < s.time_ns and j in self.results),
                      key=lambda j: self.m.sessions[j].time_ns)

    def job(self, i: int, preds: list[int]) -> SessionJob:
        s = self.m.sessions[i]
        history = []
        for j in preds:  # the trend runs over manifest dates, not over IMU clock epochs
            d = self.results[j].to_dict()
            d["session"] = {**d["session"], "imu_start_ns": self.m.sessions[j].time_ns}
            history.append(d)
        return SessionJob(s.id, s.request, tuple(history), s.time_ns,
                          tuple(str(self.result_path(j)) for j in preds))

    def tell(self, last: str) -> None:
        st = self.state
        st.done = sum(s.status != "pending" for s in self.status)
        st.failed = sum(s.status == "failed" for s in self.status)
        st.skipped = sum(s.status == "skipped" for s in self.status)
        st.last = last
        left = st.total - st.done
        if self.computed and self.t_first is not None:
            st.eta_s = (time.perf_counter() - self.t_first) / self.computed * left
        elif left == 0:
            st.eta_s = 0.0
        if self.progress is not None:
            self.progress(st)

    def save_status(self) -> None:
        data = {**header(BATCH_KIND, BATCH_VERSION), "manifest": str(self.m.path),
                "sessions": [s.to_dict() for s in self.status]}
        save_yaml(self.out / "batch.yaml", data, "mocap-calib batch status; one entry per session")

    def run_round(self, indices: list[int]) -> None:
        todo: list[int] = []
        for i in indices:
            preds = self.predecessors(i)
            st = self.status[i]
            st.priors_from = [self.m.sessions[j].id for j in preds]
            st.input_hash = input_hash(self.m.sessions[i], self.digests,
                                       [self.status[j].input_hash for j in preds])
            path = self.result_path(i)
            remove_leftovers(path.parent, within=self.out)
            if finished_hash(path) == st.input_hash:
                try:
                    self.results[i] = load_result(path)
                    st.status = "skipped"
                    self.tell(f"{st.id} finished before")
                    continue
                except InputError:
                    pass  # unreadable: calibrate again
            todo.append(i)
        if todo:
            self.compute(todo)

    def compute(self, todo: list[int]) -> None:
        if self.engine is None:
            self.engine = self.make().__enter__()
        jobs = [self.job(i, self.predecessors(i)) for i in todo]
        self.t_first = self.t_first or time.perf_counter()
        self.state.running = min(self.engine.workers, len(todo))
        self.tell("started")
        left = len(todo)
        for outcome in self.engine.run(run_session, jobs):
            i = todo[outcome.index]
            left -= 1
            self.finish(i, outcome.ok, outcome.value, outcome.error, outcome.seconds)
            self.state.running = min(self.engine.workers, left)
            self.tell(f"{self.status[i].id} {self.status[i].status}")

    def finish(self, i: int, ok: bool, result: Any, error: str, seconds: float) -> None:
        # A stop waits until the result and its status are both on disk (or neither is).
        with interrupt.deferred():
            self._finish(i, ok, result, error, seconds)

    def _finish(self, i: int, ok: bool, result: Any, error: str, seconds: float) -> None:
        st = self.status[i]
        st.seconds = seconds
        self.computed += 1
        path = self.result_path(i)
        if ok:
            result.session["batch"] = {"id": st.id, "imu_id": st.imu_id, "date": st.date,
                                       "input_hash": st.input_hash,
                                       "priors_from": list(st.priors_from)}
            try:
                save_result(path, result)
            except ConvergenceError as err:  # a number that is not finite: this session fails
                ok, error = False, str(err)
        if ok:
            self.results[i] = result
            st.status, st.error = "ok", ""
        else:
            # A result for other inputs or options would be wrong: it goes (a file that
            # is not a batch's result for this session is not the batch's to remove).
            if finished_hash(path) is not None and batch_id(path) == st.id:
                path.unlink(missing_ok=True)
            st.status, st.error = "failed", error
        self.save_status()


@dataclass
class BatchRequest:
    """Everything ``batch`` can be told (the sessions' own options are in the manifest)."""

    manifest: Path = param(MISSING, "manifest YAML listing the sessions", argument=True,
                           metavar="MANIFEST")
    out: Path = output(MISSING, "output folder (one subfolder per session)", kind="folder",
                       metavar="PATH")
    engine: str = param("local", "local (a process pool on this machine) or dask (needs "
                        "pip install 'mocap-calib\\[cluster]')", choices=ENGINES)
    scheduler: str | None = param(None, "with --engine dask: address of a running Dask "
                                  "scheduler (default: a local cluster)", show_default=False)
    workers: int | None = param(None, "worker processes (default: the number of cores; with "
                                "--scheduler, the cluster's)", lo=1, hi=4096,
                                show_default=False)
    prior_from_history: bool = param(
        False, "calibrate each session with the earlier sessions of the same imu_id as priors "
        "(a trend from two dates on)", decls=("--prior-from-history",))
    html: Path | None = output(None, "also write one HTML page over every session",
                               metavar="PATH", show_default=False)
    quiet: bool = param(False, "no progress bar", decls=("--quiet", "-q"))

    def plan(self, manifest: Manifest | None = None) -> OutputPlan:
        """The batch's own files (OUT/batch.yaml, OUT/fleet/, --html) and the manifest; with
        the ``manifest`` read, also every session's result and input files."""
        own = [self.out / "batch.yaml", *(self.out / "fleet" / f for f in FLEET_FILES)]
        outputs = [Named("--out", p) for p in own]
        inputs: list[Named] = []
        for s in manifest.sessions if manifest is not None else []:
            outputs.append(Named("--out", self.out / s.id / "calib.yaml", f"session '{s.id}'"))
            inputs += [Named(f"{self.manifest}:", n.path, f"session '{s.id}' "
                             f"{n.option.lstrip('-').replace('-', '_').lower()}")
                       for n in OutputPlan.of(s.request).inputs]
        return OutputPlan.of(self, outputs=outputs, inputs=inputs)


def run_batch(manifest_path: str | Path, out_dir: str | Path, engine: str = "local",
              workers: int | None = None, scheduler: str | None = None,
              prior_from_history: bool = False, html: Path | None = None,
              progress: ProgressCallback | None = None) -> BatchReport:
    """Calibrate every session of the manifest into ``out_dir``; see the module doc.

    Raises:
        ManifestError: the manifest's problems, one line each, before any work starts.
        InputError: an unusable OUT folder, engine or scheduler.
    """
    from mocap_calib.batch.fleet import write_fleet

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose another --out")
    request = BatchRequest(Path(manifest_path), out, html=None if html is None else Path(html))
    request.plan().check()  # the manifest is not OUT/batch.yaml, before it is read
    manifest = load_manifest(manifest_path)
    request.plan(manifest).check()
    if html is not None:
        _check_html_available()
    make_engine(engine, workers, scheduler)  # checks the choice before any work
    batch = _Batch(manifest, out, lambda: make_engine(engine, workers, scheduler),
                   prior_from_history, progress)
    try:
        out.mkdir(parents=True, exist_ok=True)
        # A run killed while writing its status or fleet files left their temporary files
        # (each session's folder is cleaned when its turn comes).
        remove_leftovers(out)
        remove_leftovers(out / "fleet", within=out)
        batch.save_status()
        for indices in _rounds(manifest.sessions, prior_from_history):
            batch.run_round(indices)
        batch.save_status()
    except BaseException as err:  # Ctrl-C included: stop the workers, keep the status true
        if batch.engine is not None:
            batch.engine.__exit__(type(err), err, None)
        if out.is_dir():
            batch.save_status()
        raise
    if batch.engine is not None:
        batch.engine.__exit__(None, None, None)
    done = [(manifest.sessions[i], r) for i, r in sorted(batch.results.items())]
    fleet_files, outliers = write_fleet(out / "fleet", done)
    files = [out / "batch.yaml", *fleet_files]
    if html is not None:
        files.append(_write_html(Path(html), [s.to_dict() for s in batch.status],
                                 out / "fleet"))
    return BatchReport(out, batch.status, files, outliers)


def _check_html_available() -> None:
    """``--html`` needs matplotlib; importing the page's writer fails early when it is
    missing."""
    from mocap_calib.workflows.report_files.pages import write_batch_report  # noqa: F401


def _write_html(path: Path, sessions: list[dict[str, Any]], fleet_dir: Path) -> Path:
    """``--html``: one self-contained page over the batch (the HTML report's batch view)."""
    from mocap_calib.workflows.report_files.pages import write_batch_report

    fleet_file = fleet_dir / "fleet.yaml"
    fleet = load_yaml(fleet_file, "fleet summary") if fleet_file.is_file() else None
    return Path(write_batch_report(path, sessions, fleet))
