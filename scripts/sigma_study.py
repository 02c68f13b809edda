"""Are the reported sigmas honest? Error / sigma over many simulated sessions.

For every seed a 90 s flight is simulated, calibrated with the default options, and every
parameter's error against the simulator's truth is divided by its reported 1-sigma, per axis.
If the sigmas are honest these ratios have an RMS near 1 (above: optimistic, below: padded),
a mean near 0 and few exceed 3. Two simulators:

- clean: white mocap noise, the noise densities the calibration assumes;
- realistic: mocap noise correlated over a time constant drawn from 0.1-0.5 s per seed (AR(1),
  same per-sample sigma), as real mocap noise is; the bias random walk is on in both;
- flying: the simulator's ``flying`` preset (a drone in flight: accelerometer white noise 10x
  its data sheet's density plus rotor vibration aliased by the IMU's sampling, the Vicon's
  attitude noise 0.2 deg, mocap noise correlated over 0.3 s; ``mocap_calib/sim/presets.py``);
  calibrated with the data sheet's densities (what a user gives).

Also printed: the worst |error| per parameter (largest axis; rotations in deg, lengths in mm,
time in ms), and the sessions whose effect tests show an effect the model lacks (none is
hidden: each is a false alarm). The sessions run on the batch engine: a local process pool, or Dask
(`pip install 'mocap-calib[cluster]'`; a LocalCluster, or the cluster at --scheduler).

Prints the table of docs/validation.md, one per simulator (``--write-doc`` rewrites its
section there).

Usage: python scripts/sigma_study.py [--seeds 30] [--first-seed 1000] [--workers 2]
       [--simulators clean,realistic] [--json out.json] [--engine local|dask]
       [--scheduler ADDRESS] [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import gtsam
import numpy as np
from _doc_section import add_doc_options, check, provenance, write
from _doc_section import table as md_table

from mocap_calib.batch.engine import map_jobs
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.sim.presets import preset_config

PARAMS = ("R_MI", "p_MI", "gyro_bias", "accel_bias", "gravity", "time_offset")

SECTIONS = ("sigma_study",)

#: The accuracy the calibration is specified for on a 90 s session (display units of UNITS).
SPECIFIED = {"R_MI": "< 0.05 deg", "p_MI": "< 2 mm", "gyro_bias": "< 2e-4 rad/s",
             "accel_bias": "< 5e-3 m/s^2", "gravity": "< 0.02 deg", "time_offset": "< 0.2 ms"}
#: Row names of the table.
LABELS = {"R_MI": "R_MI", "p_MI": "p_MI", "gyro_bias": "gyro bias", "accel_bias": "accel bias",
          "gravity": "gravity direction", "time_offset": "time offset"}


def config(simulator: str, seed: int) -> SimConfig:
    if simulator == "flying":
        return preset_config("flying", seed=seed, duration=90.0)
    corr = 0.0
    if simulator == "realistic":
        corr = float(np.random.default_rng([seed, 77]).uniform(0.1, 0.5))
    return SimConfig(seed=seed, duration=90.0, effects={"time_offset": None},
                     mocap_noise_corr=corr, noise=NoiseModel())


#: Display units of the absolute errors.
UNITS = {"R_MI": ("deg", np.degrees(1.0)), "p_MI": ("mm", 1e3), "gyro_bias": ("rad/s", 1.0),
         "accel_bias": ("m/s^2", 1.0), "gravity": ("deg", np.degrees(1.0)),
         "time_offset": ("ms", 1e3)}


def z_scores(simulator: str, seed: int) -> dict[str, Any]:
    """Per-axis error / sigma and |error| (display units) of one simulated session, and the
    effects its effect tests show."""
    sim = simulate_flight(config(simulator, seed))
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    tr = sim.truth
    R_true = so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"]))
    g_err = np.asarray(gtsam.Unit3(np.asarray(r.gravity_in_mocap)).localCoordinates(
        gtsam.Unit3(np.asarray(tr["gravity_in_mocap"]))))
    err = {
        "R_MI": so3.log(R_true.T @ r.R_marker_imu),
        "p_MI": r.translation - tr["T_marker_imu"]["translation"],
        "gyro_bias": r.gyro_bias - tr["gyro_bias"],
        "accel_bias": r.accel_bias - tr["accel_bias"],
        "gravity": -g_err,
        "time_offset": np.array([r.time_offset - tr["time_offset"]]),
    }
    sig = {"R_MI": r.sigma_rotation, "p_MI": r.sigma_translation,
           "gyro_bias": r.sigma_gyro_bias, "accel_bias": r.sigma_accel_bias,
           "gravity": r.sigma_gravity, "time_offset": np.array([r.sigma_time_offset])}
    return {"z": {k: (np.asarray(err[k]) / np.asarray(sig[k])).tolist() for k in PARAMS},
            "err": {k: (np.abs(err[k]) * UNITS[k][1]).tolist() for k in PARAMS},
            "shown": list(r.effect_tests.shown) if r.effect_tests is not None else []}


def _job(args: tuple[str, int]) -> tuple[str, int, dict[str, Any]]:
    simulator, seed = args
    return simulator, seed, z_scores(simulator, seed)


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"shown": sorted({e for r in results for e in r["shown"]}),
                           "sessions_shown": sum(bool(r["shown"]) for r in results)}
    for k in PARAMS:
        z = np.concatenate([np.asarray(r["z"][k]) for r in results])
        e = np.concatenate([np.asarray(r["err"][k]) for r in results])
        out[k] = {"n": int(z.size), "rms": float(np.sqrt(np.mean(z**2))),
                  "mean": float(np.mean(z)), "std": float(np.std(z)),
                  "max_abs": float(np.max(np.abs(z))),
                  "over_3": int(np.sum(np.abs(z) > 3)), "worst_error": float(e.max()),
                  "unit": UNITS[k][0]}
    return out


def _error(x: float, unit: str) -> str:
    if unit in ("rad/s", "m/s^2"):
        return f"{x:.2e}".replace("e-0", "e-") + f" {unit}"
    return f"{x:.2g} {unit}"


def markdown(table_by_sim: dict[str, dict[str, Any]], counts: dict[str, int],
             seeds: int, first: int) -> str:
    """The section of docs/validation.md: one table per simulator."""
    out = [provenance("sigma_study.py")]
    for sim, t in table_by_sim.items():
        out.append(f"\n{sim} simulator: {counts[sim]}/{seeds} sessions calibrated (seeds "
                   f"{first}-{first + seeds - 1}, 90 s).\n\n")
        out.append(md_table(["parameter", "specified", f"worst error ({counts[sim]} seeds)",
                          "error / sigma: RMS", "mean", "largest"],
                         [[LABELS[k], SPECIFIED[k], _error(t[k]["worst_error"], t[k]["unit"]),
                           f"{t[k]['rms']:.2f}", f"{t[k]['mean']:.2f}", f"{t[k]['max_abs']:.2f}"]
                          for k in PARAMS]))
        shown = ", ".join(f"`{e}`" for e in t["shown"]) or "none"
        out.append(f"\nEffect tests showing an effect the model lacks (none is hidden): "
                   f"{t['sessions_shown']}/{counts[sim]} sessions ({shown}).\n")
    return "".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--first-seed", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--simulators", default="clean,realistic")
    ap.add_argument("--json")
    ap.add_argument("--engine", default="local", help="local or dask")
    ap.add_argument("--scheduler", default=None, help="Dask scheduler address")
    add_doc_options(ap)
    a = ap.parse_args()
    check(a, list(SECTIONS))
    sims = a.simulators.split(",")
    jobs = [(s, seed) for s in sims for seed in range(a.first_seed, a.first_seed + a.seeds)]
    by_sim: dict[str, list[Any]] = {s: [] for s in sims}
    for o in map_jobs(_job, jobs, a.engine, a.workers, a.scheduler):
        if not o.ok:
            # A refusal is not an error / sigma; it is counted and shown.
            print(f"{jobs[o.index]} refused or failed: {o.error}", flush=True)
            continue
        simulator, _seed, z = o.value
        by_sim[simulator].append(z)
    table = {s: summarise(v) for s, v in by_sim.items()}
    print(f"error / sigma per axis, {a.seeds} seeds from {a.first_seed}, 90 s sessions")
    print("(honest sigmas: RMS 0.7-1.3, mean near 0, few |z| over 3)")
    print(f"{'parameter':<12}" + "".join(f"{s + ' RMS':>16}{s + ' mean':>16}{s + ' max':>16}"
                                         for s in sims))
    for k in PARAMS:
        print(f"{k:<12}" + "".join(f"{table[s][k]['rms']:>16.2f}{table[s][k]['mean']:>16.2f}"
                                   f"{table[s][k]['max_abs']:>16.2f}" for s in sims))
    print("worst |error| (largest axis)")
    for k in PARAMS:
        print(f"{k:<12}" + "".join(f"{table[s][k]['worst_error']:>16.3g}" for s in sims)
              + f"  {table['clean'][k]['unit'] if 'clean' in table else ''}")
    for s in sims:
        print(f"{s}: {len(by_sim[s])}/{a.seeds} sessions calibrated; effect tests show an "
              f"effect in {table[s]['sessions_shown']} ({', '.join(table[s]['shown'])})")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(table, fh, indent=1)
    text = markdown(table, {s: len(by_sim[s]) for s in sims}, a.seeds, a.first_seed)
    print(text)
    write(a, {"sigma_study": text})


if __name__ == "__main__":
    main()
