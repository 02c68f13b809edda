"""Benchmark: wall time of `mocap-calib batch` on a simulated fleet (two airframes, four dates
each, a slow bias trend), with 1 and 2 local workers and on a Dask LocalCluster.

Each run is the whole command in a fresh process into an empty output folder (start-up, pool
start, reading, calibrating, writing, fleet summary), with 1 and 2 local workers and on a Dask
LocalCluster of 2; also checks that the runs wrote the same results. Prints the table of
docs/validation.md (``--write-doc`` rewrites its section there).

Usage: python scripts/bench_batch.py [--duration S] [--repeats N] [--no-dask] [--write-doc]
       [--doc PATH]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from _doc_section import add_doc_options, check, provenance, table, write

from mocap_calib.workflows.fleet_sim import FleetSimConfig, simulate_fleet

SECTIONS = ("bench_batch",)



def _busy_s() -> float:
    """CPU seconds all processes of the machine have used so far (Linux), else 0."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]
    except OSError:
        return 0.0
    return (sum(v) - v[3] - v[4]) / os.sysconf("SC_CLK_TCK")


def _own_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(manifest: Path, out: Path, *options: str) -> tuple[float, float]:
    """Wall time of one batch, and the share of the machine's cores that other processes
    used meanwhile (the machine is shared: a busy neighbour hides any speed-up)."""
    shutil.rmtree(out, ignore_errors=True)
    code = "import sys; from mocap_calib.cli.main import main; sys.exit(main(sys.argv[1:]))"
    busy, own = _busy_s(), _own_s()
    t0 = time.perf_counter()
    # Exit code 1 (some session failed) still times the batch; the failures are counted below.
    subprocess.run([sys.executable, "-c", code, "batch", str(manifest), "--out", str(out),
                    "--quiet", *options], check=False, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    others = (_busy_s() - busy) - (_own_s() - own)
    return wall, max(0.0, others) / (wall * (os.cpu_count() or 1))


def _untimed(obj: object) -> object:
    """A result without its wall-time entries (every key that names seconds)."""
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if "seconds" not in str(k)}
    if isinstance(obj, list):
        return [_untimed(v) for v in obj]
    return obj


def results(out: Path) -> dict[str, object]:
    """Every session's result, wall times left out (they differ between any two runs)."""
    return {p.parent.name: _untimed(yaml.safe_load(p.read_text()))
            for p in sorted(out.glob("*/calib.yaml"))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=120.0, help="seconds per session")
    ap.add_argument("--repeats", type=int, default=2, help="runs per setting (the best counts)")
    ap.add_argument("--no-dask", action="store_true")
    add_doc_options(ap)
    args = ap.parse_args()
    check(args, list(SECTIONS))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        manifest, _ = simulate_fleet(root / "fleet", FleetSimConfig(duration=args.duration))
        print(f"simulated 8 sessions of {args.duration:g} s in {time.perf_counter() - t0:.1f} s")
        settings = [("local, 1 worker", ("--engine", "local", "--workers", "1")),
                    ("local, 2 workers", ("--engine", "local", "--workers", "2"))]
        if not args.no_dask:
            settings.append(("dask LocalCluster, 2 workers", ("--engine", "dask",
                                                               "--workers", "2")))
        best: dict[str, tuple[float, float]] = {}
        files: dict[str, dict[str, object]] = {}
        for r in range(args.repeats):
            for k, (name, opts) in enumerate(settings):
                out = root / f"out{k}"
                wall, others = run(manifest, out, *opts)
                best[name] = min(best.get(name, (wall, others)), (wall, others))
                files[name] = results(out)
                print(f"  run {r + 1}: {name:<30} {wall:6.2f} s   (other processes used "
                      f"{others:4.0%} of the cores)", flush=True)
        print()
        base = best[settings[0][0]][0]
        for name, _ in settings:
            wall, others = best[name]
            print(f"{name:<30} best {wall:6.2f} s   speed-up x{base / wall:.2f}   (others "
                  f"{others:.0%})")
        ref = files[settings[0][0]]
        same = all(f == ref for f in files.values())
        print(f"{len(ref)}/8 sessions calibrated; result files identical across settings "
              f"(wall-time lines aside): {same}")
    rows = [[name, f"{best[name][0]:.1f} s", f"x{base / best[name][0]:.2f}",
             f"{best[name][1]:.0%}"] for name, _ in settings]
    text = (provenance("bench_batch.py") + "\n"
            + table([f"8 sessions of {args.duration:g} s", f"best wall of {args.repeats}",
                     "speed-up", "cores used by other processes meanwhile"], rows) + "\n"
            f"{len(ref)}/8 sessions calibrated; result files identical across the settings "
            f"(wall-time lines aside): {'yes' if same else 'no'}.\n")
    print(text)
    write(args, {"bench_batch": text})


if __name__ == "__main__":
    main()
