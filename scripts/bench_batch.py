"""Benchmark: wall time of `mocap-calib batch` on a simulated fleet (two airframes, four dates
each, a slow bias trend), with 1 and 2 local workers and on a Dask LocalCluster.

Each run is the whole command in a fresh process into an empty output folder (start-up, pool
start, reading, calibrating, writing, fleet summary). Target: 2 local workers at least 1.7x
faster than 1 on a 2-core machine. Also checks that the runs wrote the same results.

Usage: python scripts/bench_batch.py [--duration S] [--repeats N] [--no-dask]
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mocap_calib.workflows.fleet_sim import FleetSimConfig, simulate_fleet

TIMING = re.compile(r"^\s*-?\s*(seconds|total_seconds|position_batch_seconds):")


def run(manifest: Path, out: Path, *options: str) -> float:
    shutil.rmtree(out, ignore_errors=True)
    code = "import sys; from mocap_calib.cli.main import main; sys.exit(main(sys.argv[1:]))"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code, "batch", str(manifest), "--out", str(out),
                    "--quiet", *options], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def results(out: Path) -> dict[str, str]:
    return {p.parent.name: "".join(line for line in p.read_text().splitlines(True)
                                   if not TIMING.match(line))
            for p in sorted(out.glob("*/calib.yaml"))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0, help="seconds per session")
    ap.add_argument("--repeats", type=int, default=2, help="runs per setting (the best counts)")
    ap.add_argument("--no-dask", action="store_true")
    args = ap.parse_args()
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
        best: dict[str, float] = {}
        files: dict[str, dict[str, str]] = {}
        for r in range(args.repeats):
            for k, (name, opts) in enumerate(settings):
                out = root / f"out{k}"
                wall = run(manifest, out, *opts)
                best[name] = min(best.get(name, wall), wall)
                files[name] = results(out)
                print(f"  run {r + 1}: {name:<30} {wall:6.2f} s", flush=True)
        print()
        base = best[settings[0][0]]
        for name, _ in settings:
            print(f"{name:<30} best {best[name]:6.2f} s   speed-up x{base / best[name]:.2f}")
        ref = files[settings[0][0]]
        same = all(f == ref for f in files.values()) and len(ref) == 8
        print(f"result files identical across settings (wall-time lines aside): {same}")


if __name__ == "__main__":
    main()
