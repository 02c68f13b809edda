"""Benchmark: wall time, CPU time, peak memory and errors against truth of `calibrate` on
simulated sessions (200 Hz IMU, 100 Hz mocap, default noise, a few ms of clock offset).

Each session runs in its own process so that peak memory (max RSS) is its own. The figures are
the calibration's own (the simulation before it is not timed; its memory is printed apart).
Per-evaluation figures make the time attributable: the position stage's evaluations of all its
windows (its main solve; the refits of the consistency and sensitivity checks run more), their
total time, and the time per 1000 window-steps (windows x padded steps).

CPU time counts all threads (the window chunks run on two). With ``--runs N`` every length runs
N times (each in its own process) and the table gives the medians and the wall-time range.
Prints the table of docs/validation.md (``--write-doc`` rewrites its section there).

Usage: python scripts/bench_calibrate.py [minutes ...] [--runs N] [--write-doc] [--doc PATH]
       (default minutes: 1 10 30 60)
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

from _doc_section import add_doc_options, check, provenance, table, write

SECTIONS = ("bench_calibrate",)


def run_one(minutes: float, seed: int = 1) -> dict:
    import numpy as np

    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.report.compare import compare
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=seed, duration=60.0 * minutes,
                                    effects={"time_offset": [0.004]}))
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    t0, c0 = time.perf_counter(), time.process_time()
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    rows = compare(res, CalibrationResult.from_dict(sim.truth))
    return {
        "minutes": minutes, "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
        "peak_rss_mb": round(rss, 1),
        "position_batch_s": res.solver.stage.get("position_batch_seconds"),
        "window_steps": res.solver.stage.get("window_steps"),
        "rss_after_simulation_mb": round(rss_before, 1),
        "stages_s": {s.name: round(s.seconds, 2) for s in res.stages},
        "errors": {r.name: [r.unit, float(f"{r.error:.3g}"), None if r.z is None
                            else float(f"{r.z:.2f}")] for r in rows},
        "windows": res.solver.windows,
        "position_evaluations": res.solver.stage.get("position_evaluations"),
        "imu_samples": int(len(sim.imu)), "chi2_per_dof": float(np.round(
            res.solver.position_chi2_per_dof, 4)),
    }


def markdown(by_minutes: dict[float, list[dict]]) -> str:
    """The section of docs/validation.md: medians per session length."""
    rows = []
    for m, rs in by_minutes.items():
        walls = [r["wall_s"] for r in rs]
        wall = f"{statistics.median(walls):.2f} s" + (
            f" ({min(walls):.2f}-{max(walls):.2f} s, median of {len(rs)})" if len(rs) > 1 else "")
        rows.append([f"{m:g} min", wall, f"{statistics.median(r['cpu_s'] for r in rs):.2f} s",
                     f"{statistics.median(r['peak_rss_mb'] for r in rs):.0f} MB"])
    return (provenance("bench_calibrate.py") + "\n"
            + table(["simulated session, in-process", "wall", "CPU", "peak RSS"], rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("minutes", nargs="*", type=float, default=[1.0, 10.0, 30.0, 60.0],
                        help="session lengths in minutes")
    parser.add_argument("--runs", type=int, default=1, help="processes per session length")
    parser.add_argument("--one", type=float, help=argparse.SUPPRESS)
    add_doc_options(parser)
    args = parser.parse_args()
    if args.one is not None:
        print(json.dumps(run_one(args.one)))
        return
    check(args, list(SECTIONS))
    by_minutes: dict[float, list[dict]] = {}
    for m in args.minutes:
        for _ in range(args.runs):
            out = subprocess.run([sys.executable, __file__, f"--one={m}"], capture_output=True,
                                 text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            by_minutes.setdefault(m, []).append(r)
            _print_run(m, r)
    results = [rs[0] for rs in by_minutes.values()]
    if len(results) > 1:
        base = results[0]
        for r in results[1:]:
            ratio = (r["wall_s"] / base["wall_s"]) / (r["minutes"] / base["minutes"])
            print(f"time per minute, {r['minutes']:.0f} min vs {base['minutes']:.0f} min: "
                  f"x{ratio:.2f} (1.00 = linear)")
    text = markdown(by_minutes)
    print(text)
    write(args, {"bench_calibrate": text})


def _print_run(m: float, r: dict) -> None:
    n_eval, t_eval = r["position_evaluations"], r["position_batch_s"]
    per = 1e3 * t_eval / max(n_eval, 1)
    per_k = per / max(r["windows"] * r["window_steps"] / 1000.0, 1e-9)
    print(f"{m:5.0f} min: {r['wall_s']:7.2f} s wall, {r['cpu_s']:7.2f} s CPU, peak RSS "
          f"{r['peak_rss_mb']:7.1f} MB (after simulating: {r['rss_after_simulation_mb']:.0f}"
          f" MB), {r['windows']} windows x {r['window_steps']} steps, {n_eval} evaluations "
          f"in {t_eval:.2f} s ({per:.0f} ms each, {per_k:.1f} ms per 1000 window-steps), "
          f"stages {r['stages_s']}", flush=True)
    for name, (unit, err, z) in r["errors"].items():
        print(f"         {name:<17} error {err:<10.3g} {unit:<6} |err|/sigma {z}")


if __name__ == "__main__":
    main()
