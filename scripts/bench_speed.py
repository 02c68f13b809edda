"""Benchmark: the first run after installing against later ones, peak memory against mocap2gt,
and the command line's own cost against ``calibrate()`` in-process, side by side in one run.

- A recorded session (``--real IMU.csv,MOCAP.csv``): the install step (``mocap-calib compile``
  into an empty kernel cache), the first ``calibrate`` after it, later (warm) runs, and the first
  run into an empty cache without the install step (it compiles the kernels).
- ``--peer WRAPPER``: mocap2gt on the same session through its wrapper (``WRAPPER --imu ..
  --mocap .. --out .. [--peer-args]``, e.g. /work/peer/run_mocap2gt.sh), its peak memory and
  time.
- Simulated sessions (``--minutes``, default 10 and 30; ``mocap-calib simulate --seed 7``):
  ``calibrate DIR`` as a user runs it (start-up, reading, writing) against ``calibrate()`` on
  the same arrays in a process that has read them already (the command line's own cost is the
  difference).

Every run is its own process: wall time, CPU time of all its threads and peak RSS (``wait4``).
Each kind of run is repeated ``--runs`` times (not the first runs, which are first only once);
the table gives the minimum and median wall time, the median CPU time and the largest peak
RSS (MiB: ``ru_maxrss`` / 1024, the peer's too). The machine's other load moves wall times; CPU
times move less. Runs see the environment without ``PYTHONDONTWRITEBYTECODE``, as a user's.

Prints the table of docs/validation.md; ``--write-doc`` rewrites its section there.

Usage: python scripts/bench_speed.py [--real IMU.csv,MOCAP.csv] [--peer WRAPPER]
       [--peer-args "..."] [--minutes 10 30] [--runs 3] [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from _doc_section import add_doc_options, check, provenance, table, write

SECTIONS = ("bench_speed",)
HEADER = ["run", "wall (min / median)", "CPU (median)", "peak RSS (largest)"]
#: The environment of every run: a user's (bytecode caches written and read).
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


@dataclass(frozen=True)
class Run:
    """One process: wall and CPU seconds, peak RSS (MB)."""

    wall: float
    cpu: float
    rss: float


def measure(cmd: list[str], env: dict[str, str] | None = None) -> Run:
    """Run ``cmd`` (its output discarded); exit with its error if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**ENV, **(env or {})})
    _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        sys.exit(f"error: {shlex.join(cmd)} exited with {code}:\n{err}")
    return Run(wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0)


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "mocap_calib", *args]


def in_process(session: Path, env: dict[str, str]) -> Run:
    """``calibrate()`` on a session read beforehand, in a fresh process (see :func:`_inproc`)."""
    out = subprocess.run([sys.executable, __file__, "--inproc", str(session)],
                         capture_output=True, text=True, env={**ENV, **env})
    if out.returncode != 0:
        sys.exit(f"error: the in-process run failed:\n{out.stderr}")
    r = json.loads(out.stdout.strip().splitlines()[-1])
    return Run(r["wall"], r["cpu"], r["rss"])


def _inproc(session: str) -> None:
    """Read the session as ``calibrate`` does, then time ``calibrate()`` on its arrays with the
    options the command line would pass (no output written)."""
    import resource
    from dataclasses import replace

    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate
    from mocap_calib.workflows.calibrate import CalibrateRequest
    from mocap_calib.workflows.session import InputSpec, NoiseSpec, load_session

    request = CalibrateRequest(inputs=InputSpec(mav0=(Path(session),)))
    loaded = load_session(request.inputs, None)
    opts = replace(CalibrationOptions(), noise=request.noise.resolve(
        loaded.sensor_noise, NoiseSpec.sensor_file(request.inputs)))
    t0, c0 = time.perf_counter(), time.process_time()
    calibrate(loaded.imu, loaded.mocap, opts)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"wall": wall, "cpu": cpu, "rss": rss}))


def cells(label: str, runs: list[Run]) -> list[str]:
    walls = [r.wall for r in runs]
    wall = (f"{min(walls):.2f} / {statistics.median(walls):.2f} s (of {len(runs)})"
            if len(runs) > 1 else f"{walls[0]:.2f} s")
    return [label, wall, f"{statistics.median(r.cpu for r in runs):.2f} s",
            f"{max(r.rss for r in runs):.0f} MiB"]


def show(row: list[str]) -> None:
    print(f"  {row[0]:<62} {row[1]:>24} wall {row[2]:>9} CPU {row[3]:>8}", flush=True)


def real_rows(a: argparse.Namespace, cache: Path, tmp: Path) -> tuple[list[list[str]],
                                                                      list[str], Run]:
    """Rows of the recorded session; the notes; its warm median run."""
    imu, mocap = a.real.split(",")
    out = str(tmp / "real.yaml")
    args = ["calibrate", "--imu", imu, "--mocap", mocap, "--out", out, "--quiet"]
    env = {"NUMBA_CACHE_DIR": str(cache)}
    name = a.real_label
    rows = []
    install = measure(cli("compile"), env)
    rows.append(cells("install step: `mocap-calib compile` into an empty kernel cache",
                      [install]))
    show(rows[-1])
    first = measure(cli(*args), env)
    rows.append(cells(f"{name}: first `calibrate` after the install step", [first]))
    show(rows[-1])
    warm = [measure(cli(*args), env) for _ in range(a.runs)]
    rows.append(cells(f"{name}: later runs", warm))
    show(rows[-1])
    bare = measure(cli(*args), {"NUMBA_CACHE_DIR": str(tmp / "empty")})
    rows.append(cells(f"{name}: first run without the install step (compiles)", [bare]))
    show(rows[-1])
    mid = sorted(warm, key=lambda r: r.wall)[len(warm) // 2]
    notes = [f"{name}: first run after the install step / median later run: wall "
             f"x{first.wall / statistics.median(r.wall for r in warm):.2f}, CPU "
             f"x{first.cpu / statistics.median(r.cpu for r in warm):.2f}"]
    if a.peer:
        peer = [measure([a.peer, "--imu", imu, "--mocap", mocap, "--out",
                         str(tmp / "peer.yaml"), *shlex.split(a.peer_args)])
                for _ in range(a.peer_runs)]
        rows.append(cells(f"{name}: mocap2gt (`{' '.join([Path(a.peer).name, a.peer_args])}`)",
                          peer))
        show(rows[-1])
        notes.append(f"{name}: peak RSS {max(r.rss for r in warm):.0f} MiB (largest of the later "
                     f"runs) against mocap2gt's {max(r.rss for r in peer):.0f} MiB")
    return rows, notes, mid


def simulated_rows(a: argparse.Namespace, cache: Path, tmp: Path) -> tuple[list[list[str]],
                                                                           list[str]]:
    env = {"NUMBA_CACHE_DIR": str(cache)}
    rows, notes = [], []
    for m in a.minutes:
        session = tmp / f"sim{m:g}"
        measure(cli("simulate", str(session), "--duration", f"{60 * m:g}", "--seed", "7"))
        line = [measure(cli("calibrate", str(session), "--out", str(tmp / "sim.yaml"),
                            "--quiet"), env) for _ in range(a.runs)]
        rows.append(cells(f"{m:g} min simulated: `calibrate DIR` (command line)", line))
        show(rows[-1])
        inner = [in_process(session, env) for _ in range(a.runs)]
        rows.append(cells(f"{m:g} min simulated: `calibrate()` on its arrays (in-process)",
                          inner))
        show(rows[-1])
        notes.append(f"{m:g} min: the command line's own cost (median wall difference) "
                     f"{statistics.median(r.wall for r in line) - statistics.median(r.wall for r in inner):.2f} s, "  # noqa: E501
                     f"CPU {statistics.median(r.cpu for r in line) - statistics.median(r.cpu for r in inner):.2f} s")  # noqa: E501
    return rows, notes


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", help="a recorded session: IMU.csv,MOCAP.csv (EuRoC CSVs)")
    ap.add_argument("--real-label", default="real session",
                    help="how the table names the recorded session")
    ap.add_argument("--peer", help="mocap2gt's wrapper script (run on --real)")
    ap.add_argument("--peer-args", default="", help="more arguments for the wrapper")
    ap.add_argument("--peer-runs", type=int, default=1)
    ap.add_argument("--minutes", type=float, nargs="*", default=[10.0, 30.0],
                    help="simulated session lengths (none: skip them)")
    ap.add_argument("--runs", type=int, default=3, help="repeats of each kind of run")
    ap.add_argument("--inproc", help=argparse.SUPPRESS)
    add_doc_options(ap)
    a = ap.parse_args()
    if a.inproc:
        _inproc(a.inproc)
        return 0
    check(a, list(SECTIONS))
    if a.real and (len(a.real.split(",")) != 2
                   or not all(Path(p).is_file() for p in a.real.split(","))):
        print(f"error: --real {a.real}: give IMU.csv,MOCAP.csv (two files that exist)",
              file=sys.stderr)
        return 2
    if a.peer and not a.real:
        print("error: --peer runs on the --real session: give --real too", file=sys.stderr)
        return 2
    rows, notes = [], []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        cache = tmp / "kernels"
        if a.real:
            got, more, _ = real_rows(a, cache, tmp)
            rows += got
            notes += more
        else:
            measure(cli("compile"), {"NUMBA_CACHE_DIR": str(cache)})
        got, more = simulated_rows(a, cache, tmp)
        rows += got
        notes += more
    text = (provenance("bench_speed.py") + "\n" + table(HEADER, rows) + "\n"
            + "\n".join(f"- {n}" for n in notes) + "\n")
    print(text)
    write(a, {"bench_speed": text})
    return 0


if __name__ == "__main__":
    sys.exit(main())
