"""Benchmark: what choosing the model costs. ``calibrate`` (default model), ``calibrate --model
auto`` and ``diagnose`` through the command line, side by side on the same sessions in one run:
wall time, CPU time (all threads) and peak RSS of each process (``os.wait4``), and the ratios
to ``calibrate``. Acceptance: ``--model auto`` and ``diagnose`` at most 2x ``calibrate``.

Sessions: mocap2gt's real 65 s session (``peer/m2g_session`` beside ``shared``), EuRoC V2_03
(``shared/data``) and a simulated 10-minute session (``simulate DIR --duration 600 --seed 7``,
written once to ``--sessions``). A session whose files are missing is skipped with a line.
Each command runs ``--runs`` times (median), after ``mocap-calib compile`` (the install step),
so that no timed run compiles a kernel.

Usage: python scripts/bench_models.py [--runs 1] [--only m2g,euroc,sim10] [--sessions DIR]
       [--write-doc] [--doc PATH]
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

from _doc_section import add_doc_options, check, provenance, table, write
from _shared_data import DATA

SECTIONS = ("bench_models",)
#: mocap2gt's real session: ``peer/m2g_session`` beside ``shared`` (of this checkout or above).
PEER = next((p / "peer" / "m2g_session" for p in (DATA.parents[1], *DATA.parents[1].parents)
             if (p / "peer" / "m2g_session").is_dir()), DATA.parents[1] / "peer" / "m2g_session")
COMMANDS = (("calibrate", ["calibrate"]), ("auto", ["calibrate", "--model", "auto"]),
            ("diagnose", ["diagnose"]))
LIMIT = 2.0


def sessions(sim_dir: Path) -> dict[str, tuple[str, list[str], list[Path]]]:
    """Name -> (label, input arguments, files that must exist)."""
    mav0 = DATA / "euroc_V2_03_difficult" / "mav0"
    return {
        "m2g": ("mocap2gt's real 65 s session", ["--imu", str(PEER / "imu.csv"), "--mocap",
                                                 str(PEER / "mocap.csv")],
                [PEER / "imu.csv", PEER / "mocap.csv"]),
        "euroc": ("EuRoC V2_03 (114 s)", [str(mav0)], [mav0]),
        "sim10": ("simulated 10 min (seed 7)", [str(sim_dir / "sim10")], [sim_dir / "sim10"]),
    }


def run_once(args: list[str]) -> tuple[float, float, float, int]:
    """Wall s, CPU s, peak RSS MB and exit code of one CLI run."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "mocap_calib", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = proc.stderr.read() if proc.stderr else b""
    _, status, ru = os.wait4(proc.pid, 0)
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        print(err.decode(errors="replace"), file=sys.stderr)
    return time.perf_counter() - t0, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0, code


def measure(inputs: list[str], runs: int, tmp: Path) -> dict[str, tuple[float, float, float]]:
    """Per command, the medians of ``runs`` runs (wall s, CPU s, peak MB)."""
    out = {}
    for name, cmd in COMMANDS:
        rows = []
        for _ in range(runs):
            wall, cpu, rss, code = run_once([*cmd, *inputs, "--out", str(tmp / f"{name}.yaml"),
                                             "--quiet"])
            if code != 0:
                raise SystemExit(f"error: {' '.join(cmd)} exited with {code}")
            rows.append((wall, cpu, rss))
        out[name] = tuple(statistics.median(r[i] for r in rows) for i in range(3))
        w, c, m = out[name]
        print(f"  {name:<10} {w:6.2f} s wall  {c:6.2f} s CPU  {m:5.0f} MB", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--only", type=lambda s: s.split(","), default=None)
    ap.add_argument("--sessions", type=Path, default=Path("/tmp/mocap_calib_bench_models"))
    add_doc_options(ap)
    a = ap.parse_args()
    check(a, list(SECTIONS))
    sim = a.sessions / "sim10"
    if (a.only is None or "sim10" in a.only) and not (sim / "truth.yaml").exists():
        subprocess.run([sys.executable, "-m", "mocap_calib", "simulate", str(sim),
                        "--duration", "600", "--seed", "7"], check=True, capture_output=True)
    # The install step: no timed run compiles a kernel.
    subprocess.run([sys.executable, "-m", "mocap_calib", "compile"], check=True,
                   capture_output=True)
    rows, ok, complete = [], True, True
    for key, (label, inputs, needs) in sessions(a.sessions).items():
        if a.only and key not in a.only:
            complete = False
            continue
        if not all(p.exists() for p in needs):
            print(f"{label}: skipped ({', '.join(str(p) for p in needs if not p.exists())} "
                  "missing)")
            complete = False
            continue
        print(label, flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            m = measure(inputs, a.runs, Path(tmp))
        cal = m["calibrate"]
        cells = [label]
        for name, _ in COMMANDS:
            w, c, r = m[name]
            cells.append(f"{w:.1f} s / {c:.1f} s / {r:.0f} MB")
        for name in ("auto", "diagnose"):
            rw, rc = m[name][0] / cal[0], m[name][1] / cal[1]
            ok &= max(rw, rc) <= LIMIT
            cells.append(f"{rw:.2f} / {rc:.2f}")
        rows.append(cells)
    header = ["session", "`calibrate` wall / CPU / peak", "`--model auto`", "`diagnose`",
              "auto / calibrate (wall / CPU)", "diagnose / calibrate"]
    text = table(header, rows)
    print(text)
    print(f"acceptance (auto and diagnose <= {LIMIT:g}x calibrate, wall and CPU): "
          + ("met" if ok else "NOT met"))
    if complete:
        write(a, {"bench_models": provenance("bench_models.py") + "\n" + text})
    else:
        write(a, {})
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
