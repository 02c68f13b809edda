"""Benchmark: the first run after installing against later ones, peak memory against mocap2gt,
and the command line's own cost against ``calibrate()`` in-process, side by side in one run.

- A recorded session (``--real IMU.csv,MOCAP.csv``): the install step (``mocap-calib compile``
  into an empty kernel cache), the first ``calibrate`` after it, later (warm) runs, and the first
  run into an empty cache without the install step (it compiles the kernels).
- ``--peer WRAPPER`` (or ``MOCAP2GT_WRAPPER``): mocap2gt on the same session through its
  wrapper (``WRAPPER --imu .. --mocap .. --out .. PEER_ARGS``), its estimator's peak memory and
  time as the wrapper's result file records them (``run:``; the conversions around it are not
  counted). ``--peer-args`` (or ``MOCAP2GT_ARGS``) passes the noise model and settings, e.g.
  mocap2gt's shipped configuration: ``--noise noise.yaml --gravity 9.8 --relin 1
  --variable-toff --imu-freq 200 --stock``. Without a wrapper the row is skipped, with a line
  saying so.
- Simulated sessions (``--minutes``, default 10 and 30; ``mocap-calib simulate --seed 7``):
  ``calibrate DIR`` as a user runs it (start-up, reading, writing) against ``calibrate()`` on
  the same arrays in a process that has read them already (the command line's own cost is the
  difference).

Every run is its own process: wall time, CPU time of all its threads and peak RSS (``wait4``).
Each kind of run is repeated ``--runs`` times (not the first runs, which are first only once);
the table gives the minimum and median wall time, the median CPU time and the largest peak
RSS (MiB: ``ru_maxrss`` / 1024, the peer's too). The machine's other load moves wall times; CPU
times move less. Runs see the environment without ``PYTHONDONTWRITEBYTECODE``, as a user's.

Below the table, each figure against its bound: the first run after the install step within
1.5x of a later one (wall), the recorded session's peak RSS at or below mocap2gt's, the command
line on 10 and 30 simulated minutes within 5 and 12 s (median wall). The load average before and
after is printed with them: the machine's other work moves wall times.

Prints the tables of docs/validation.md; ``--write-doc`` rewrites its section there.

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

import yaml
from _doc_section import add_doc_options, check, provenance, table, write

SECTIONS = ("bench_speed",)
HEADER = ["run", "wall (min / median)", "CPU (median)", "peak RSS (largest)"]
BOUND_HEADER = ["figure", "measured", "bound", "within"]
#: The first ``calibrate`` after the install step: at most this many times a later run's wall.
FIRST_RUN_RATIO = 1.5
#: The command line on a simulated session of this many minutes: at most these seconds (wall).
CLI_SECONDS = {10.0: 5.0, 30.0: 12.0}
#: The environment of every run: a user's (bytecode caches written and read).
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


@dataclass(frozen=True)
class Run:
    """One process: wall and CPU seconds, peak RSS (MiB)."""

    wall: float
    cpu: float
    rss: float


@dataclass
class Table:
    """The runs' rows, the notes under them and each figure against its bound."""

    rows: list[list[str]]
    notes: list[str]
    bounds: list[list[str]]

    def add(self, label: str, runs: list[Run]) -> None:
        self.rows.append(cells(label, runs))
        show(self.rows[-1])

    def bound(self, figure: str, measured: float, limit: float, fmt: str) -> None:
        self.bounds.append([figure, fmt.format(measured), fmt.format(limit),
                            "yes" if measured <= limit else "**no**"])
        print(f"  bound: {figure}: {fmt.format(measured)} against {fmt.format(limit)}", flush=True)


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


def median_wall(runs: list[Run]) -> float:
    return statistics.median(r.wall for r in runs)


def peer_wrapper(a: argparse.Namespace) -> str | None:
    """mocap2gt's wrapper (``--peer`` or ``MOCAP2GT_WRAPPER``), or None (a line says why)."""
    wrapper = a.peer or os.environ.get("MOCAP2GT_WRAPPER")
    if not wrapper:
        print("  mocap2gt: skipped (no wrapper given: --peer or MOCAP2GT_WRAPPER)", flush=True)
        return None
    if not (Path(wrapper).is_file() and os.access(wrapper, os.X_OK)):
        print(f"  mocap2gt: skipped ({wrapper} is not an executable file)", flush=True)
        return None
    return wrapper


def peer_run(cmd: list[str], out: Path) -> Run:
    """The wrapper's run; mocap2gt's own wall, CPU and peak RSS from its result file."""
    measure(cmd)
    try:
        run = yaml.safe_load(out.read_text())["run"]
        return Run(float(run["wall_s"]), float(run["cpu_s"]), float(run["peak_rss_kb"]) / 1024)
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        sys.exit(f"error: {out}: no run.wall_s/cpu_s/peak_rss_kb in the wrapper's result "
                 f"({exc!r}); give the wrapper that writes them (see --help)")


def real_rows(a: argparse.Namespace, t: Table, cache: Path, tmp: Path) -> None:
    """The recorded session's rows, notes and bounds."""
    imu, mocap = a.real.split(",")
    args = ["calibrate", "--imu", imu, "--mocap", mocap, "--out", str(tmp / "real.yaml"),
            "--quiet"]
    env = {"NUMBA_CACHE_DIR": str(cache)}
    name = a.real_label
    t.add("install step: `mocap-calib compile` into an empty kernel cache",
          [measure(cli("compile"), env)])
    first = measure(cli(*args), env)
    t.add(f"{name}: first `calibrate` after the install step", [first])
    warm = [measure(cli(*args), env) for _ in range(a.runs)]
    t.add(f"{name}: later runs", warm)
    t.add(f"{name}: first run without the install step (compiles)",
          [measure(cli(*args), {"NUMBA_CACHE_DIR": str(tmp / "empty")})])
    ratio = first.wall / median_wall(warm)
    t.notes.append(f"{name}: first run after the install step / median later run: wall "
                   f"x{ratio:.2f}, CPU "
                   f"x{first.cpu / statistics.median(r.cpu for r in warm):.2f}")
    t.bound(f"{name}: first `calibrate` after the install step / later run (wall)", ratio,
            FIRST_RUN_RATIO, "x{:.2f}")
    wrapper = peer_wrapper(a)
    ours = max(r.rss for r in [first, *warm])
    if wrapper is None:
        t.notes.append(f"{name}: peak RSS {ours:.0f} MiB (mocap2gt not run)")
        return
    peer_args = a.peer_args if a.peer_args is not None else os.environ.get("MOCAP2GT_ARGS", "")
    peer = [peer_run([wrapper, "--imu", imu, "--mocap", mocap, "--out", str(out),
                      *shlex.split(peer_args)], out)
            for out in (tmp / f"peer{k}.yaml" for k in range(a.peer_runs))]
    t.add(f"{name}: mocap2gt (`{' '.join([Path(wrapper).name, peer_args])}`; estimator only)",
          peer)
    theirs = max(r.rss for r in peer)
    t.notes.append(f"{name}: peak RSS {ours:.0f} MiB (largest of the first and later runs) "
                   f"against mocap2gt's {theirs:.0f} MiB")
    t.bound(f"{name}: peak RSS of `calibrate` (MiB; bound: mocap2gt's)", ours, theirs,
            "{:.0f}")


def simulated_rows(a: argparse.Namespace, t: Table, cache: Path, tmp: Path) -> None:
    env = {"NUMBA_CACHE_DIR": str(cache)}
    for m in a.minutes:
        session = tmp / f"sim{m:g}"
        measure(cli("simulate", str(session), "--duration", f"{60 * m:g}", "--seed", "7"))
        line = [measure(cli("calibrate", str(session), "--out", str(tmp / "sim.yaml"),
                            "--quiet"), env) for _ in range(a.runs)]
        t.add(f"{m:g} min simulated: `calibrate DIR` (command line)", line)
        inner = [in_process(session, env) for _ in range(a.runs)]
        t.add(f"{m:g} min simulated: `calibrate()` on its arrays (in-process)", inner)
        cpu = statistics.median(r.cpu for r in line) - statistics.median(r.cpu for r in inner)
        t.notes.append(f"{m:g} min: the command line's own cost (median wall difference) "
                       f"{median_wall(line) - median_wall(inner):.2f} s, CPU {cpu:.2f} s")
        if m in CLI_SECONDS:
            t.bound(f"{m:g} min simulated: `calibrate DIR` (median wall, s)", median_wall(line),
                    CLI_SECONDS[m], "{:.2f}")


def load_line(start: tuple[float, float, float]) -> str:
    end = os.getloadavg()
    return (f"Load average (1 / 5 / 15 min) on {os.cpu_count()} cores: "
            f"{' / '.join(f'{x:.1f}' for x in start)} before, "
            f"{' / '.join(f'{x:.1f}' for x in end)} after.")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", help="a recorded session: IMU.csv,MOCAP.csv (EuRoC CSVs)")
    ap.add_argument("--real-label", default="real session",
                    help="how the table names the recorded session")
    ap.add_argument("--peer", help="mocap2gt's wrapper script, run on --real (default: "
                    "$MOCAP2GT_WRAPPER; none: the row is skipped)")
    ap.add_argument("--peer-args", help="more arguments for the wrapper (default: "
                    "$MOCAP2GT_ARGS)")
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
    load = os.getloadavg()
    t = Table([], [], [])
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        cache = tmp / "kernels"
        if a.real:
            real_rows(a, t, cache, tmp)
        else:
            print("  recorded session: skipped (no --real): no first-run or memory figures",
                  flush=True)
            measure(cli("compile"), {"NUMBA_CACHE_DIR": str(cache)})
        simulated_rows(a, t, cache, tmp)
    text = (provenance("bench_speed.py").rstrip("\n") + " " + load_line(load) + "\n\n"
            + table(HEADER, t.rows) + "\n" + "\n".join(f"- {n}" for n in t.notes) + "\n")
    if t.bounds:
        text += "\n" + table(BOUND_HEADER, t.bounds)
    print(text)
    write(a, {"bench_speed": text})
    return 0


if __name__ == "__main__":
    sys.exit(main())
