"""IMU gaps and several takes, measured on simulated sessions against their truth (nothing
here is computed by the code under test's own expectations). Prints the three sections of
docs/validation.md (``--write-doc`` rewrites them there).

1. Gap acceptance: one 90 s session (seed 31) calibrated without IMU gaps and with the gap
   pattern of real PX4 logs punched in (36 dropouts of 12-161 ms, stalls of 0.5 s and 3 s):
   errors against truth and |error|/sigma.
2. Two takes of one rig (seeds 21, 22, clock offsets 4 ms and -11 ms): the shared T_MI's
   sigma jointly and per take alone, each take's clock-offset error.
3. The diagnosis of two 40 s takes of one rig (seeds 31, 32, clock offsets 4 ms and -9 ms)
   with a hidden accel_delay of 4 ms, from the base model: what it finds, the joint estimate
   and each take's own.

Usage: python scripts/drone_logs_study.py [--json PATH] [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
import json
import time

import gtsam
import numpy as np
from _doc_section import add_doc_options, check, provenance, table, write

from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import Recording, calibrate, calibrate_takes
from mocap_calib.sim.flight import SimConfig, simulate_flight

SECTIONS = ("imu_gaps_study", "takes_study", "takes_diagnosis_study")

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
        gaps = res.imu_gaps.to_dict() if res.imu_gaps is not None else {}
        out[name] = {**_errors(res, sim.truth), "seconds": round(time.perf_counter() - t0, 1),
                     "imu_gaps": {k: v for k, v in gaps.items() if k != "gaps"}}
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
    from mocap_calib.core.model.effects import Model

    sims = [simulate_flight(SimConfig(seed=s, duration=40.0, rig_seed=91, effects={
        "time_offset": [td], "accel_delay": [0.004]})) for s, td in ((31, 0.004), (32, -0.009))]
    t0 = time.perf_counter()
    rep = diagnose_takes([Recording(s.imu, s.mocap, f"take{i + 1}")
                          for i, s in enumerate(sims)], DiagnoseOptions(start_model=Model()))
    out = {"found": rep.found, "seconds": round(time.perf_counter() - t0, 1),
           "set_aside": rep.implausible,
           "added": [{"effect": st.added, "value": st.added_params, "sigma": st.added_sigma,
                      "takes": next(c.takes for c in st.candidates if c.effect == st.added)}
                     for st in rep.steps if st.added]}
    print("diagnose", json.dumps(out, default=float), flush=True)
    return out


def gaps_markdown(g: dict) -> str:
    """Section imu_gaps_study: errors with and without the PX4 gap pattern."""
    rows = [[label, f"{r['rotation_deg']:.2g} deg", f"{r['translation_mm']:.3g} mm",
             f"{1e3 * r['time_offset_ms']:.1f} us",
             ", ".join(f"{r[k]:.2f}" for k in ("z_rotation", "z_translation", "z_time_offset",
                                                "z_gravity"))]
            for label, r in (("no gaps", g["no_gaps"]), ("PX4 gap pattern", g["px4_gaps"]))]
    gaps = g["px4_gaps"]["imu_gaps"]
    return (provenance("drone_logs_study.py") + "\n"
            + table(["90 s, seed 31", "R_MI error", "p_MI error", "t_d error",
                     "largest \\|error\\|/sigma (R, p, t_d, gravity)"], rows) + "\n"
            f"With the gap pattern the calibration found {gaps.get('count')} gaps, "
            f"{gaps.get('total_s', 0):.1f} s in all ({100 * gaps.get('total_s', 0) / 90:.1f} % "
            f"of the session): {gaps.get('trimmed_samples', 0)} sample(s) trimmed at the start, "
            f"{gaps.get('bridged')} bridged, {gaps.get('split')} longer than 0.5 s splitting the "
            f"session into {gaps.get('segments')} segments.\n")


def takes_markdown(t: dict) -> str:
    """Section takes_study: the shared T_MI's sigma per take alone and jointly."""
    a, j = t["alone"], t["joint"]
    rows = [[f"take {k + 1} alone", f"{r['rotation_deg']:.2g} deg", f"{r['translation_mm']:.2g} mm",
             f"{1e3 * r['time_offset_error_ms']:.1f} us"] for k, r in enumerate(a)]
    rows.append(["both together", f"{j['rotation_deg']:.2g} deg", f"{j['translation_mm']:.2g} mm",
                 " / ".join(f"{1e3 * e:.1f} us" for e in j["time_offset_error_ms"])])
    best_r = min(r["rotation_deg"] for r in a)
    best_p = min(r["translation_mm"] for r in a)
    return (provenance("drone_logs_study.py") + "\n"
            + table(["two 60 s takes", "sigma R_MI (largest axis)", "sigma p_MI (largest axis)",
                     "t_d error (per take)"], rows) + "\n"
            f"The joint sigma is {j['rotation_deg'] / best_r:.2f}x (rotation) and "
            f"{j['translation_mm'] / best_p:.2f}x (translation) the better take's alone.\n")


def _scalar(x) -> float:
    while isinstance(x, dict):
        x = next(iter(x.values()))
    return float(np.ravel(np.asarray(x, dtype=float))[0])


def _value(effect: str, value, sigma) -> str:
    from mocap_calib.core.model.effects import EFFECTS

    unit = EFFECTS[effect].unit
    scale, unit = (1e3, "ms") if unit == "s" else (1.0, unit)
    return f"{scale * _scalar(value):.2f} +- {scale * _scalar(sigma):.2f} {unit}"


def diagnosis_markdown(d: dict) -> str:
    """Section takes_diagnosis_study: what the joint diagnosis found, jointly and per take."""
    parts = []
    for a in d["added"]:
        per = "; ".join(f"take {r['take']} alone {_value(a['effect'], r['value'], r['sigma'])} "
                        f"(log10 p {r['log10_p']:.0f})" for r in a["takes"])
        parts.append(f"`{a['effect']}`: jointly {_value(a['effect'], a['value'], a['sigma'])}; "
                     + per)
    found = ", ".join(f"`{e}`" for e in d["found"]) or "nothing"
    return (provenance("drone_logs_study.py") + "\n"
            f"Two 40 s takes with a hidden `accel_delay` of 4 ms, diagnosed from the base model "
            f"({d['seconds']:.0f} s): found {found}. " + ". ".join(parts) + ".\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="also write the figures to this file")
    add_doc_options(ap)
    a = ap.parse_args()
    check(a, list(SECTIONS))
    figures = {"gap_acceptance": gap_acceptance(), "two_takes": two_takes(),
               "diagnose_two_takes": diagnose_two_takes()}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(figures, f, indent=1, default=float)
    sections = {"imu_gaps_study": gaps_markdown(figures["gap_acceptance"]),
                "takes_study": takes_markdown(figures["two_takes"]),
                "takes_diagnosis_study": diagnosis_markdown(figures["diagnose_two_takes"])}
    for text in sections.values():
        print(text)
    write(a, sections)


if __name__ == "__main__":
    main()
