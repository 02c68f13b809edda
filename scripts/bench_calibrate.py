"""Benchmark: wall time, peak memory and errors against truth of `calibrate` on simulated
sessions (200 Hz IMU, 100 Hz mocap, default noise, a few ms of clock offset).

Each session runs in its own process so that peak memory (max RSS) is its own.
Targets: a 10-minute session in under 20 s and 1.5 GB on 2 cores; cost linear in length.

Usage: python scripts/bench_calibrate.py [minutes ...]      (default: 1 10 60)
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time


def run_one(minutes: float, seed: int = 1) -> dict:
    import numpy as np

    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.sim.flight import SimConfig, simulate_flight
    from mocap_calib.workflows.compare import compare

    sim = simulate_flight(SimConfig(seed=seed, duration=60.0 * minutes,
                                    effects={"time_offset": [0.004]}))
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    t0 = time.perf_counter()
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    rows = compare(res, CalibrationResult.from_dict(sim.truth))
    return {
        "minutes": minutes, "wall_s": round(wall, 2), "peak_rss_mb": round(rss, 1),
        "rss_after_simulation_mb": round(rss_before, 1),
        "stages_s": {s.name: round(s.seconds, 2) for s in res.stages},
        "errors": {r.name: [r.unit, float(f"{r.error:.3g}"), None if r.z is None
                            else float(f"{r.z:.2f}")] for r in rows},
        "windows": res.solver.get("windows"),
        "position_evaluations": res.solver.get("position_evaluations"),
        "imu_samples": int(len(sim.imu)), "chi2_per_dof": float(np.round(
            res.solver["position_chi2_per_dof"], 4)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("minutes", nargs="*", type=float, default=[1.0, 10.0, 60.0],
                        help="session lengths in minutes")
    parser.add_argument("--one", type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one is not None:
        print(json.dumps(run_one(args.one)))
        return
    minutes = args.minutes
    results = []
    for m in minutes:
        out = subprocess.run([sys.executable, __file__, f"--one={m}"], capture_output=True,
                             text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        results.append(r)
        print(f"{m:5.0f} min: {r['wall_s']:7.2f} s, peak RSS {r['peak_rss_mb']:7.1f} MB "
              f"(after simulating: {r['rss_after_simulation_mb']:.0f} MB), "
              f"{r['windows']} windows, {r['position_evaluations']} evaluations, "
              f"stages {r['stages_s']}", flush=True)
        for name, (unit, err, z) in r["errors"].items():
            print(f"         {name:<17} error {err:<10.3g} {unit:<6} |err|/sigma {z}")
    if len(results) > 1:
        base = results[0]
        for r in results[1:]:
            ratio = (r["wall_s"] / base["wall_s"]) / (r["minutes"] / base["minutes"])
            print(f"time per minute, {r['minutes']:.0f} min vs {base['minutes']:.0f} min: "
                  f"x{ratio:.2f} (1.00 = linear)")


if __name__ == "__main__":
    main()
