"""Accuracy study: calibrate many simulated sessions and compare every estimate with the
simulator's truth; per parameter, the worst error and the spread of error / sigma (near 1 when
the reported uncertainty is honest). Prints the table of docs/validation.md (``--write-doc``
rewrites its section there).

The sessions run on the batch engine: a local process pool, or Dask (`pip install
'mocap-calib[cluster]'`; a LocalCluster, or the cluster at --scheduler).

Usage: python scripts/accuracy_study.py [--seeds N] [--first-seed S] [--duration S]
                                        [--effect NAME=VALUE ...] [--engine local|dask]
                                        [--workers W] [--scheduler ADDRESS]
                                        [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse

import numpy as np
from _doc_section import add_doc_options, check, number, provenance, table, write

from mocap_calib.batch.engine import map_jobs

SECTIONS = ("accuracy_study",)


def run_case(job: tuple[int, float, tuple[str, ...]]) -> dict[str, tuple[str, float, float]]:
    """Per parameter, the error / sigma of every component (tangent spaces as the sigmas)."""
    seed, duration, effects = job
    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.report.compare import compare
    from mocap_calib.sim.flight import SimConfig, parse_effect, simulate_flight

    rng = np.random.default_rng(seed)
    parsed = dict(parse_effect(e) for e in effects) or {
        "time_offset": [float(rng.uniform(-0.01, 0.01))]}
    sim = simulate_flight(SimConfig(seed=seed, duration=duration, effects=parsed))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    rows = compare(res, CalibrationResult.from_dict(sim.truth))
    return {r.name: (r.unit, r.error, r.z if r.z is not None else float("nan")) for r in rows}


def markdown(per: dict[str, tuple[str, list[list[float]]]], done: int, total: int,
             duration: float) -> str:
    """The section of docs/validation.md."""
    rows = []
    for name, (unit, vals) in per.items():
        a = np.asarray(vals)
        rows.append([name, f"{number(a[:, 0].max())} {unit}", f"{np.nanmedian(a[:, 1]):.2f}",
                     f"{np.nanmax(a[:, 1]):.2f}"])
    return (provenance("accuracy_study.py") + "\n"
            f"{done}/{total} sessions of {duration:g} s calibrated.\n\n"
            + table(["parameter", "worst error", "largest \\|error\\|/sigma per session: median",
                     "max"], rows))


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
    add_doc_options(ap)
    args = ap.parse_args()
    check(args, list(SECTIONS))
    jobs = [(s, args.duration, tuple(args.effect))
            for s in range(args.first_seed, args.first_seed + args.seeds)]
    outcomes = map_jobs(run_case, jobs, args.engine, args.workers, args.scheduler)
    per: dict[str, tuple[str, list[list[float]]]] = {}
    for o in outcomes:
        if not o.ok:
            print(f"seed {jobs[o.index][0]}: {o.error}")
            continue
        for name, (unit, err, z) in o.value.items():
            per.setdefault(name, (unit, []))[1].append([err, z])
    text = markdown(per, sum(o.ok for o in outcomes), len(jobs), args.duration)
    print(text)
    write(args, {"accuracy_study": text})


if __name__ == "__main__":
    main()
