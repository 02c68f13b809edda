"""Figures of the README's "Drone flight logs" section, measured on simulated sessions against
their truth (nothing here is computed by the code under test's own expectations).

1. Gap acceptance: one 90 s session (seed 31) calibrated without IMU gaps and with the gap
   pattern of real PX4 logs punched in (36 dropouts of 12-161 ms, stalls of 0.5 s and 3 s):
   errors against truth and |error|/sigma.
2. Two takes of one rig (seeds 21, 22, clock offsets 4 ms and -11 ms): the shared T_MI's
   sigma jointly and per take alone, each take's clock-offset error.
3. The diagnosis of two 40 s takes of one rig (seeds 31, 32, clock offsets 4 ms and -9 ms)
   with a hidden accel_delay of 4 ms, from the base model: what it finds, the joint estimate
   and each take's own.

Usage: python scripts/drone_logs_study.py [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import time

import gtsam
import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import Recording, calibrate, calibrate_takes
from mocap_calib.sim.flight import SimConfig, simulate_flight

PX4_LIKE = {"imu_dropouts": [36], "imu_stalls": [0.5, 3.0]}
OPTS = CalibrationOptions(segments=0, sensitivity=False)


def _errors(res, truth) -> dict[str, float]:
    T = truth["T_marker_imu"]
    d_rot = so3.log(so3.quat_to_rotmat(np.array(T["rotation_wxyz"])).T
                    @ so3.quat_to_rotmat(res.rotation_wxyz))
    d_p = res.translation - np.array(T["translation"])
    d_t = res.time_offset - truth["time_offset"]
    d_g = np.asarray(gtsam.Unit3(res.gravity_in_mocap).localCoordinates(
        gtsam.Unit3(np.array(truth["gravity_in_mocap"]))))
    return {"rotation_deg": float(np.degrees(np.linalg.norm(d_rot))),
            "translation_mm": float(1e3 * np.linalg.norm(d_p)),
            "time_offset_ms": float(1e3 * abs(d_t)),
            "z_rotation": float(np.abs(d_rot / res.sigma_rotation).max()),
            "z_translation": float(np.abs(d_p / res.sigma_translation).max()),
            "z_time_offset": float(abs(d_t) / res.sigma_time_offset),
            "z_gravity": float(np.abs(d_g / res.sigma_gravity).max())}


def gap_acceptance() -> dict:
    out = {}
    for name, extra in (("no_gaps", {}), ("px4_gaps", PX4_LIKE)):
        sim = simulate_flight(SimConfig(seed=31, duration=90.0,
                                        effects={"time_offset": [0.006], **extra}))
        t0 = time.perf_counter()
        res = calibrate(sim.imu, sim.mocap, OPTS)
        out[name] = {**_errors(res, sim.truth), "seconds": round(time.perf_counter() - t0, 1),
                     "imu_gaps": {k: v for k, v in res.imu_gaps.items() if k != "gaps"}}
        print(name, json.dumps(out[name]), flush=True)
    return out


def two_takes() -> dict:
    sims = [simulate_flight(SimConfig(seed=s, duration=60.0, rig_seed=77,
                                      effects={"time_offset": [td]}))
            for s, td in ((21, 0.004), (22, -0.011))]
    joint = calibrate_takes([Recording(s.imu, s.mocap, f"take{i + 1}")
                             for i, s in enumerate(sims)], OPTS)
    alone = [calibrate(s.imu, s.mocap, OPTS) for s in sims]

    def sig(r) -> dict[str, float]:
        return {"rotation_deg": float(np.degrees(np.max(r.sigma_rotation))),
                "translation_mm": float(1e3 * np.max(r.sigma_translation))}

    out = {"joint": {**sig(joint), "time_offset_error_ms": [
        float(1e3 * abs(t.to_dict()["time_offset"] - s.truth["time_offset"]))
        for t, s in zip(joint.takes, sims, strict=True)]},
        "alone": [{**sig(r), "time_offset_error_ms": float(
            1e3 * abs(r.time_offset - s.truth["time_offset"]))}
            for r, s in zip(alone, sims, strict=True)]}
    print("takes", json.dumps(out), flush=True)
    return out


def diagnose_two_takes() -> dict:
    from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose_takes

    sims = [simulate_flight(SimConfig(seed=s, duration=40.0, rig_seed=91, effects={
        "time_offset": [td], "accel_delay": [0.004]})) for s, td in ((31, 0.004), (32, -0.009))]
    t0 = time.perf_counter()
    rep = diagnose_takes([Recording(s.imu, s.mocap, f"take{i + 1}")
                          for i, s in enumerate(sims)], DiagnoseOptions())
    out = {"found": rep.found, "seconds": round(time.perf_counter() - t0, 1),
           "set_aside": rep.implausible,
           "added": [{"effect": st.added, "value": st.added_params, "sigma": st.added_sigma,
                      "takes": next(c.takes for c in st.candidates if c.effect == st.added)}
                     for st in rep.steps if st.added]}
    print("diagnose", json.dumps(out, default=float), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="also write the figures to this file")
    a = ap.parse_args()
    figures = {"gap_acceptance": gap_acceptance(), "two_takes": two_takes(),
               "diagnose_two_takes": diagnose_two_takes()}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(figures, f, indent=1, default=float)


if __name__ == "__main__":
    main()
