"""Benchmark: the `calibrate` command on a recorded session, as a user runs it (start-up, reading,
every stage, writing): wall time, CPU time (all threads) and peak memory of each run.

The session is not in the repository: give its path, a mav0 folder or ``IMU.csv,MOCAP.csv``
(EuRoC CSV layout). Each run is its own process (its figures are its own, from ``wait4``).
With ``--cold`` the first run compiles the kernels into an empty cache (as the first run after
installing does) and the next runs load them from it (a fresh process with a warm cache).

Prints the session's row of the table of docs/validation.md; ``--write-doc`` puts it into
that section (replacing the row with the same ``--label``, or adding it).

Usage: python scripts/bench_session.py PATH [--runs 3] [--cold] [--label TEXT] [--write-doc]
       [--doc PATH] [-- extra calibrate options]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _doc_section import add_doc_options, check, read_section, table, upsert_row, write

SECTIONS = ("bench_session",)
HEADER = ["session (`calibrate` as a user runs it)", "wall", "CPU", "peak RSS"]


def run_once(args: list[str], env: dict[str, str]) -> tuple[float, float, float, int]:
    """Wall s, CPU s, peak RSS MB and exit code of one CLI run."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "mocap_calib", "calibrate", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, **env})
    _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        print(proc.stderr.read().decode(errors="replace"), file=sys.stderr)
    proc.stderr.close()
    return wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0, proc.returncode


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", help="mav0 folder, or IMU.csv,MOCAP.csv")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--cold", action="store_true", help="first run into an empty kernel cache")
    ap.add_argument("--label", help="the row's first cell (default: the path and options)")
    add_doc_options(ap)
    argv = sys.argv[1:]
    cut = argv.index("--") if "--" in argv else len(argv)
    a = ap.parse_args(argv[:cut])
    extra = argv[cut + 1:]
    check(a, list(SECTIONS))
    parts = a.path.split(",")
    inputs = ["--imu", parts[0], "--mocap", parts[1]] if len(parts) == 2 else [a.path]
    for p in parts:
        if not Path(p).exists():
            print(f"error: {p} does not exist", file=sys.stderr)
            return 2
    with tempfile.TemporaryDirectory() as tmp:
        args = [*inputs, "--out", str(Path(tmp) / "calib.yaml"), "--quiet",
                *extra]
        env = {"NUMBA_CACHE_DIR": str(Path(tmp) / "kernels")} if a.cold else {}
        rows = []
        for i in range(a.runs):
            wall, cpu, rss, code = run_once(args, env)
            kind = ("cold (compiles)" if i == 0 else "warm cache") if a.cold else "run"
            print(f"{kind:>16} {i + 1}: {wall:6.2f} s wall, {cpu:6.2f} s CPU, {rss:6.0f} MB peak"
                  f"{'' if code == 0 else f', exit {code}'}", flush=True)
            if code != 0:
                return code
            rows.append((wall, cpu, rss))
    warm = rows[1:] if a.cold else rows
    if warm:
        print(f"median of {len(warm)}: {statistics.median(r[0] for r in warm):.2f} s wall, "
              f"{statistics.median(r[1] for r in warm):.2f} s CPU, "
              f"{statistics.median(r[2] for r in warm):.0f} MB peak")
    # The row: the cold run alone with --cold (what a first run after installing costs), else
    # the medians of the runs.
    use = rows[:1] if a.cold else rows
    label = a.label or " ".join([a.path, *extra, *(["(first run, compiles)"] if a.cold else [])])
    cells = [label, f"{statistics.median(r[0] for r in use):.2f} s"
             + (f" (median of {len(use)})" if len(use) > 1 else ""),
             f"{statistics.median(r[1] for r in use):.2f} s",
             f"{statistics.median(r[2] for r in use):.0f} MB"]
    print(table(HEADER, [cells]))
    if a.write_doc:
        write(a, {"bench_session": upsert_row(read_section(a.doc, "bench_session"), cells)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
