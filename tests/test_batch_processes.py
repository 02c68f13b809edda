"""A batch's processes die with it: after ``kill -9`` of ``mocap-calib batch`` (the local process
engine) no worker (~250 MB each) and no multiprocessing resource tracker lives on, and a batch
resumed after such kills leaves no process behind when it ends.

Only the batch's own process is killed, never its process group (a terminal's Ctrl-C or a
``killpg`` would reach the workers directly and hide the question). Its processes are found by
their session (the batch is started in a session of its own) and by the pids recorded before
the kill, with their start times (a pid may be reused).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mocap_calib.workflows.simulate import simulate_to_folder

PROC = Path("/proc")
pytestmark = pytest.mark.skipif(not (PROC / "self" / "stat").exists(),
                                reason="needs Linux's /proc to find the processes")
ROOT = Path(__file__).resolve().parents[1]


def _stat(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat from the state on (index 0: state, 1: ppid, 3: session,
    19: start time), or None when the process is gone."""
    try:
        text = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    return text.rsplit(")", 1)[1].split()


def _live(pid: int, start: str | None = None) -> bool:
    """The process runs (a zombie has ended; another process may have the pid by now)."""
    st = _stat(pid)
    return st is not None and st[0] not in ("Z", "X") and (start is None or st[19] == start)


def _in_session(sid: int) -> dict[int, str]:
    """Live processes of session ``sid`` and their start times."""
    out = {}
    for entry in PROC.iterdir():
        if entry.name.isdigit() and (st := _stat(int(entry.name))) is not None:
            if int(st[3]) == sid and st[0] not in ("Z", "X"):
                out[int(entry.name)] = st[19]
    return out


def _start(manifest: Path, out: Path) -> subprocess.Popen:
    """The batch in a session of its own; its output goes to a file (a pipe would stay open
    as long as any worker holds it)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH",
                                                                                   "")]))
    log = (out.parent / f"batch-{time.monotonic_ns()}.log").open("w")
    with log:
        return subprocess.Popen([sys.executable, "-m", "mocap_calib", "batch", str(manifest),
                                 "--out", str(out), "--workers", "2", "--quiet"], cwd=ROOT,
                                env=env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _kill(proc: subprocess.Popen) -> dict[int, str]:
    """``kill -9`` of the batch alone; returns what was left running 5 s later, killed."""
    children = {p: s for p, s in _in_session(proc.pid).items() if p != proc.pid}
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    left = _gone_within(children, proc.pid, 5.0)
    for pid in left:  # leave nothing behind, whatever the verdict
        os.kill(pid, signal.SIGKILL)
    return {p: children.get(p, "") for p in left}


def _wait_for_workers(proc: subprocess.Popen, n: int, timeout: float = 120.0) -> dict[int, str]:
    t0 = time.monotonic()
    while True:
        assert proc.poll() is None, f"the batch ended with {proc.returncode}"
        children = {p: s for p, s in _in_session(proc.pid).items() if p != proc.pid}
        workers = [p for p in children
                   if b"spawn_main" in (PROC / str(p) / "cmdline").read_bytes()]
        if len(workers) >= n:
            time.sleep(1.0)  # into their first sessions
            return {p: s for p, s in _in_session(proc.pid).items() if p != proc.pid}
        assert time.monotonic() - t0 < timeout, f"no {n} workers: {children}"
        time.sleep(0.1)


def _gone_within(children: dict[int, str], sid: int, seconds: float) -> list[int]:
    """The processes still alive after ``seconds`` (empty: all gone)."""
    t0 = time.monotonic()
    while True:
        left = [p for p, s in children.items() if _live(p, s)] + list(_in_session(sid))
        if not left or time.monotonic() - t0 > seconds:
            return sorted(set(left))
        time.sleep(0.1)


@pytest.fixture(scope="module")
def manifest(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fleet")
    simulate_to_folder(root / "s", seed=2, duration=15.0)
    path = root / "manifest.yaml"
    path.write_text("sessions:\n" + "".join(
        f"  - {{id: s{k}, imu_id: a, date: 2024-01-0{k + 1}, mav0: s}}\n" for k in range(4)))
    return path


def test_kill_9_of_a_batch_takes_its_workers_along(manifest: Path, tmp_path: Path) -> None:
    """Workers and the resource tracker lived on after ``kill -9`` of their batch."""
    (tmp_path / "out").mkdir()
    proc = _start(manifest, tmp_path / "out")
    children = _wait_for_workers(proc, 2)
    assert len(children) >= 3, children  # two workers and the resource tracker
    left = _kill(proc)
    assert not left, f"still running 5 s after the batch was killed: {sorted(left)}"


@pytest.mark.slow
def test_a_batch_resumed_after_kills_leaves_no_process(manifest: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    for _ in range(2):
        proc = _start(manifest, out)
        _wait_for_workers(proc, 2)
        assert not _kill(proc)
    proc = _start(manifest, out)
    seen: dict[int, str] = {}
    while proc.poll() is None:
        seen.update({p: s for p, s in _in_session(proc.pid).items() if p != proc.pid})
        time.sleep(0.2)
    assert proc.returncode == 0
    assert len(list(out.glob("s*/calib.yaml"))) == 4
    assert not _gone_within(seen, proc.pid, 5.0)
