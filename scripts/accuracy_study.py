"""Accuracy study: calibrate many simulated sessions and compare every estimate with the
simulator's truth; per parameter, the worst error and the spread of error / sigma (near 1 when
the reported uncertainty is honest). The README's accuracy table comes from such a run.

The sessions run on the batch engine: a local process pool, or Dask (`pip install
'mocap-calib[cluster]'`; a LocalCluster, or the cluster at --scheduler).

Usage: python scripts/accuracy_study.py [--seeds N] [--first-seed S] [--duration S]
                                        [--effect NAME=VALUE ...] [--engine local|dask]
                                        [--workers W] [--scheduler ADDRESS]
"""

from __future__ import annotations

import argparse

import numpy as np

from mocap_calib.batch.engine import map_jobs


def run_case(job: tuple[int, float, tuple[str, ...]]) -> dict[str, list[float]]:
    """Per parameter, the error / sigma of every component (tangent spaces as the sigmas)."""
    seed, duration, effects = job
    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.sim.flight import SimConfig, parse_effect, simulate_flight
    from mocap_calib.workflows.compare import compare

    rng = np.random.default_rng(seed)
    parsed = dict(parse_effect(e) for e in effects) or {
        "time_offset": [float(rng.uniform(-0.01, 0.01))]}
    sim = simulate_flight(SimConfig(seed=seed, duration=duration, effects=parsed))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    rows = compare(res, CalibrationResult.from_dict(sim.truth))
    return {r.name: [r.error, r.z if r.z is not None else float("nan")] for r in rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--first-seed", type=int, default=500)
    ap.add_argument("--duration", type=float, default=90.0)
    ap.add_argument("--effect", action="append", default=[],
                    help="simulate this effect too (as 'mocap-calib simulate --effect')")
    ap.add_argument("--engine", default="local", help="local or dask")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--scheduler", default=None, help="Dask scheduler address")
    args = ap.parse_args()
    jobs = [(s, args.duration, tuple(args.effect))
            for s in range(args.first_seed, args.first_seed + args.seeds)]
    outcomes = map_jobs(run_case, jobs, args.engine, args.workers, args.scheduler)
    per: dict[str, list[list[float]]] = {}
    for o in outcomes:
        if not o.ok:
            print(f"seed {jobs[o.index][0]}: {o.error}")
            continue
        for name, (err, z) in o.value.items():
            per.setdefault(name, []).append([err, z])
    print(f"{sum(o.ok for o in outcomes)}/{len(jobs)} sessions of {args.duration:g} s")
    print("worst error (unit of workflows.compare); per session the largest |err|/sigma over "
          "the axes: its median and max over the sessions")
    print(f"{'parameter':<18} {'worst error':>12} {'median':>7} {'max':>7}")
    for name, vals in per.items():
        a = np.asarray(vals)
        print(f"{name:<18} {a[:, 0].max():12.3g} {np.nanmedian(a[:, 1]):7.2f} "
              f"{np.nanmax(a[:, 1]):7.2f}")


if __name__ == "__main__":
    main()
