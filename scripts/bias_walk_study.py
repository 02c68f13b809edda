"""The session-mean biases' sigmas under the bias random walk: the model's and the sandwich's.

The position stage reports, per component, the larger of two statistical sigmas: the model's
(``H^-1``) and the sandwich's (the windows' own score spread), both of the bias's mean over
time (``core/position/session_mean.py``). This study separates the two covariances on
sessions where the noise model is exactly the simulator's (clean simulator, white mocap noise,
``--fixed-noise`` with the true densities), once with the biases' random walk as the data
sheet gives it and once with the walk switched off in both the simulator and the calibration.
It prints, per bias, the RMS of error / sigma under the
model's sigma, the sandwich's and the reported statistical one (their larger), and the median
sandwich / model sigma ratio. And the same sessions' score test of an accelerometer bias drift
(which none has): how often its p-value falls below 5 % (model-based and as reported, the weaker
of the model's and the windows' evidence); a calibrated test: about 5 %.

Each window's filter lets the bias wander from the window's knot, and the window's end bias
meets the next knot with the walk over the gap (the end rows), so the wander counts once. If
the model covariance of the session-mean bias is right, switching the walk off leaves its RMS
where it was.

Usage: python scripts/bias_walk_study.py [--seeds 40] [--first-seed 2000] [--workers 2]
       [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

import numpy as np
from _doc_section import add_doc_options, check, provenance, write
from _doc_section import table as md_table

from mocap_calib.batch.engine import map_jobs
from mocap_calib.core.checks.effect_scores import effect_scores
from mocap_calib.core.model.parameters import ACCEL_BIAS, GYRO_BIAS
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import Recording, fit_takes
from mocap_calib.sim.flight import SimConfig, simulate_flight

SECTIONS = ("bias_walk_study",)
CASES = {"bias walk of the data sheet": None,
         "no bias walk": {"accelerometer_random_walk": 1e-7, "gyroscope_random_walk": 1e-9}}
BIASES = (GYRO_BIAS, ACCEL_BIAS)


def _job(args: tuple[str, int]) -> tuple[str, dict[str, Any]]:
    case, seed = args
    nz = NoiseModel() if CASES[case] is None else replace(NoiseModel(), **CASES[case])
    sim = simulate_flight(SimConfig(seed=seed, duration=90.0, effects={"time_offset": None},
                                    noise=nz))
    opts = CalibrationOptions(noise=nz, noise_from_data=False)
    fitted = fit_takes([Recording(sim.imu, sim.mocap)], opts)
    ratio = fitted.pos.figures.sandwich_over_model_sigma
    out = {}
    for p in BIASES:
        e = fitted.result.estimate(p)
        err = np.asarray(e.value) - np.asarray(sim.truth[p.name])
        stat = np.asarray(e.sigma)  # the larger of the model's and the sandwich's
        r = np.asarray(ratio[p.name])
        model = stat / np.maximum(1.0, r)
        out[p.name] = {"model": (err / model).tolist(), "sandwich": (err / (model * r)).tolist(),
                       "stat": (err / stat).tolist(), "ratio": r.tolist()}
    drift = next(t for t in effect_scores(fitted.pos, opts.model)
                 if t.effect == "accel_bias_drift")
    out["drift_log10_p"] = [drift.model_log10_p, drift.log10_p]
    return case, out


def rows(results: dict[str, list[dict[str, Any]]]) -> list[list[str]]:
    def rms(z: np.ndarray) -> str:
        return f"{np.sqrt(np.mean(z**2)):.2f}"
    out = []
    for case, runs in results.items():
        for p in BIASES:
            z = {k: np.concatenate([np.asarray(r[p.name][k]) for r in runs])
                 for k in ("model", "sandwich", "stat", "ratio")}
            out.append([case, p.symbol, str(len(runs)), rms(z["model"]), rms(z["sandwich"]),
                        rms(z["stat"]), f"{np.median(z['ratio']):.2f}"])
    return out


def drift_rows(results: dict[str, list[dict[str, Any]]]) -> list[list[str]]:
    out = []
    for case, runs in results.items():
        lp = np.array([r["drift_log10_p"] for r in runs])
        below = np.mean(lp < np.log10(0.05), axis=0)
        out.append([case, str(len(runs)), f"{100 * below[0]:.0f} %", f"{100 * below[1]:.0f} %"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=2000)
    ap.add_argument("--workers", type=int, default=2)
    add_doc_options(ap)
    a = ap.parse_args()
    check(a, list(SECTIONS))
    jobs = [(c, s) for c in CASES for s in range(a.first_seed, a.first_seed + a.seeds)]
    results: dict[str, list[dict[str, Any]]] = {c: [] for c in CASES}
    for o in map_jobs(_job, jobs, "local", a.workers, None):
        if not o.ok:
            print(f"{jobs[o.index]} refused or failed: {o.error}", flush=True)
            continue
        case, z = o.value
        results[case].append(z)
    text = (provenance("bias_walk_study.py") + "\n"
            + md_table(["simulated sessions (90 s, noise model exact)", "bias", "sessions",
                        "error / sigma RMS: model", "sandwich", "reported (larger)",
                        "sandwich / model sigma (median)"], rows(results))
            + "\n" + md_table(["simulated sessions (no drift)", "sessions",
                               "accel_bias_drift test p < 5 %: model-based", "as reported"],
                              drift_rows(results)))
    print(text)
    write(a, {"bias_walk_study": text})


if __name__ == "__main__":
    main()
