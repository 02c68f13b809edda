"""Hit rate and false-alarm rate of `mocap-calib diagnose` on simulated sessions.

For every canonical effect, the simulator hides it at its default (realistic) magnitude in a
session; the diagnosis starts from the base model and must name that effect first, and nothing
else. Sessions with no hidden effect must give "none": clean ones, and realistic ones whose
mocap noise is correlated over 0.3 s (noise is not an effect; the bias random walk is on in
all). Pairs hidden together must both be found, and nothing else. Also reported: the final
low-band residual RMS over the noise floor. Prints the table of docs/validation.md
(``--write-doc`` rewrites its section there).

Usage: python scripts/diagnose_hit_rate.py [--seeds N] [--duration S] [--jobs J] [--extra-nulls M]
       [--effects a,b,...] [--json out.json] [--engine local|dask] [--scheduler ADDRESS]
       [--write-doc] [--doc PATH]
The cases run on the batch engine: a local process pool, or Dask (`pip install
'mocap-calib[cluster]'`; a LocalCluster, or the cluster at --scheduler).
"""

from __future__ import annotations

import argparse
import json
import os
import time

from _doc_section import add_doc_options, check, provenance, table, write

from mocap_calib.batch.engine import map_jobs
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, EFFECTS

SECTIONS = ("diagnose_hit_rate",)

PAIRS = (("gyro_scale_misalignment", "accel_scale_misalignment"),
         ("time_offset", "clock_drift"))
REALISTIC_CORR_S = 0.3


def run_case(args: tuple[tuple[str, ...], int, float, float]) -> dict:
    hidden, seed, duration, corr = args
    from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose
    from mocap_calib.core.model.effects import Model
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=seed, duration=duration,
                                    effects={e: None for e in hidden}, mocap_noise_corr=corr))
    t0 = time.perf_counter()
    # From the base model: a hidden clock offset is one of the effects to find.
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=Model()))
    r = rep.final_residuals
    return {"hidden": list(hidden), "seed": seed, "mocap_noise_corr": corr, "found": rep.found,
            "implausible": [x["effect"] for x in rep.implausible],
            "unexplained": rep.unexplained is not None,
            "gyro_ratio": r.ratio("gyro"), "accel_ratio": r.ratio("accel"),
            "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=90.0)
    ap.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 2)))
    ap.add_argument("--first-seed", type=int, default=1000)
    ap.add_argument("--extra-nulls", type=int, default=0,
                    help="more sessions with nothing hidden, for a tighter false-alarm rate")
    ap.add_argument("--effects", default=",".join(CANONICAL_EFFECTS))
    ap.add_argument("--no-pairs", action="store_true")
    ap.add_argument("--json")
    ap.add_argument("--engine", default="local", help="local or dask")
    ap.add_argument("--scheduler", default=None, help="Dask scheduler address")
    add_doc_options(ap)
    args = ap.parse_args()
    check(args, list(SECTIONS))
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    d = args.duration
    cases = [((e,), s, d, 0.0) for e in args.effects.split(",") if e for s in seeds]
    cases += [((), s, d, 0.0) for s in seeds] + [((), s, d, REALISTIC_CORR_S) for s in seeds]
    if not args.no_pairs:
        cases += [(pair, s, d, 0.0) for pair in PAIRS for s in seeds]
    extra = range(args.first_seed + args.seeds, args.first_seed + args.seeds + args.extra_nulls)
    cases += [((), s, d, c) for s in extra for c in (0.0, REALISTIC_CORR_S)]
    outcomes = map_jobs(run_case, cases, args.engine, args.jobs, args.scheduler)
    for o in outcomes:
        if not o.ok:
            print(f"case {cases[o.index][:2]} failed: {o.error}", flush=True)
    results = [o.value for o in outcomes if o.ok]
    hits = total = false_alarms = nulls = pair_ok = pairs = 0
    ratios = []
    per_effect: dict[str, list[tuple[int, int]]] = {}
    nulls_by_corr: dict[float, list[int]] = {}
    per_pair: dict[str, list[int]] = {}
    for r in results:
        hidden = r["hidden"]
        ratios.append(max(r["gyro_ratio"], r["accel_ratio"]))
        if not hidden:
            nulls += 1
            false_alarms += bool(r["found"])
            nulls_by_corr.setdefault(r["mocap_noise_corr"], []).append(int(bool(r["found"])))
        elif len(hidden) == 1:
            ok = bool(r["found"]) and r["found"][0] == hidden[0]
            total += 1
            hits += ok
            per_effect.setdefault(hidden[0], []).append((int(ok), int(r["found"] == hidden)))
        else:
            pairs += 1
            both = set(r["found"]) == set(hidden)
            pair_ok += both
            per_pair.setdefault("+".join(hidden), []).append(int(both))
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}),
              flush=True)
    print()
    for e, v in per_effect.items():
        print(f"{e:<26} named first in {sum(a for a, _ in v)}/{len(v)}, "
              f"found nothing else in {sum(b for _, b in v)}/{len(v)}")
    for c, v in nulls_by_corr.items():
        print(f"nothing hidden, mocap noise corr {c:g} s: false alarms {sum(v)}/{len(v)}")
    for pr, v in per_pair.items():
        print(f"pair {pr}: both found, nothing else, in {sum(v)}/{len(v)}")
    print(f"hit rate (right name first): {hits}/{total} = {hits / max(total, 1):.1%}")
    print(f"false alarms (no hidden effect, something named): {false_alarms}/{nulls} = "
          f"{false_alarms / max(nulls, 1):.1%}")
    print(f"pairs hidden together: both found, nothing else, in {pair_ok}/{pairs}")
    worst = max(ratios)
    within = sum(x <= 1.05 for x in ratios)
    print(f"final residual RMS / noise floor (worst sensor per case): max {worst:.3f}, "
          f"within 5 % in {within}/{len(ratios)}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    text = markdown(results, args.first_seed, args.seeds, d)
    print(text)
    write(args, {"diagnose_hit_rate": text})


def markdown(results: list[dict], first: int, seeds: int, duration: float) -> str:
    """The section of docs/validation.md (counts over the cases that ran)."""
    from mocap_calib.sim.injected import sim_of

    rows, singles, nulls, pairs = [], {}, {}, {}
    for r in results:
        h = r["hidden"]
        if len(h) == 1:
            singles.setdefault(h[0], []).append(r)
        elif not h:
            nulls.setdefault(r["mocap_noise_corr"], []).append(r)
        else:
            pairs.setdefault(tuple(h), []).append(r)
    hits = total = 0
    for e, rs in singles.items():
        first_ok = sum(bool(r["found"]) and r["found"][0] == e for r in rs)
        alone = sum(r["found"] == [e] for r in rs)
        hits, total = hits + first_ok, total + len(rs)
        rows.append([f"`{e}` ({sim_of(EFFECTS[e]).default:g})", f"{first_ok}/{len(rs)}",
                     f"{alone}/{len(rs)}"])
    rows.append(["**hit rate**", f"**{hits}/{total} = {hits / max(total, 1):.0%}**", ""])
    for c, rs in sorted(nulls.items()):
        what = "white mocap noise" if c == 0 else f"mocap noise correlated over {c:g} s"
        rows.append([f"nothing hidden, {what}: false alarms",
                     f"{sum(bool(r['found']) for r in rs)}/{len(rs)}", ""])
    for pr, rs in pairs.items():
        rows.append([" + ".join(f"`{e}`" for e in pr) + " hidden together: both found, "
                     "nothing else", f"{sum(set(r['found']) == set(pr) for r in rs)}/{len(rs)}",
                     ""])
    worst = [max(r["gyro_ratio"], r["accel_ratio"]) for r in results]
    white = [w for w, r in zip(worst, results, strict=True) if r["mocap_noise_corr"] == 0]
    corr = [w for w, r in zip(worst, results, strict=True) if r["mocap_noise_corr"] != 0]
    ratio = f"max {max(worst):.2f}; within 5 % in {sum(w <= 1.05 for w in white)}/{len(white)} " \
            "sessions with white mocap noise"
    if corr:
        lo, hi = f"{min(corr):.2f}", f"{max(corr):.2f}"
        ratio += f"; {lo if lo == hi else f'{lo}-{hi}'} with correlated mocap noise"
    rows.append(["final low-band residual RMS / noise floor, worst sensor per session", ratio,
                 ""])
    secs = [r["seconds"] for r in results]
    rows.append(["run time of one diagnosis", f"{min(secs):.0f}-{max(secs):.0f} s", ""])
    return (provenance("diagnose_hit_rate.py") + "\n"
            f"{len(results)} cases, seeds {first}-{first + seeds - 1}, {duration:g} s sessions."
            "\n\n" + table(["hidden (the simulator's default magnitude)", "named first",
                             "`found` holds nothing else"], rows))


if __name__ == "__main__":
    main()
