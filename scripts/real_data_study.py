"""Real-data study: calibrate every recording in ../shared/data, in full and in thirds, and
with the noise densities scaled by 3 and 1/3.

Prints, per recording: the full-session answer (R_MI against the reference, p_MI, t_d, exit),
the largest pairwise |difference| / combined sigma between the thirds for R_MI, p_MI and t_d,
and how far (in sigmas) the answer moves when the noise densities are scaled. This is computed
here from separate runs, independently of the result's own ``consistency`` section.

The PX4 flight logs (``px4/*.ulg``, no mocap topic logged) are run through the command line
as a user would: ``calibrate`` (its exit code and refusal line) and ``allan`` on their IMU (its
answer, or exit code and refusal line).

Prints the tables of docs/validation.md; ``--write-doc`` rewrites its sections there (the
recordings' table only from a full run: every recording, thirds and noise scalings).

Usage: python scripts/real_data_study.py [--json out.json] [--only euroc,broad21,px4]
       [--no-thirds] [--no-sensitivity] [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _doc_section import ROOT, add_doc_options, check, command_line, provenance, table, write
from _shared_data import DATA

from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.errors import CalibrationError
from mocap_calib.workflows.session import InputSpec, NoiseSpec, load_session

RECORDINGS = {
    "euroc": ("EuRoC V2_03", InputSpec(mav0=(DATA / "euroc_V2_03_difficult" / "mav0",))),
    "broad15": ("BROAD 15", InputSpec(imu=DATA / "broad_15_undisturbed_fast_translation_A" /
                                      "data.csv", mocap=DATA /
                                      "broad_15_undisturbed_fast_translation_A" / "data.csv",
                                      columns="broad")),
    "broad21": ("BROAD 21", InputSpec(imu=DATA / "broad_21_undisturbed_fast_combined" /
                                      "data.csv", mocap=DATA /
                                      "broad_21_undisturbed_fast_combined" / "data.csv",
                                      columns="broad")),
    "broad27": ("BROAD 27", InputSpec(imu=DATA / "broad_27_disturbed_phone_vibration_B" /
                                      "data.csv", mocap=DATA /
                                      "broad_27_disturbed_phone_vibration_B" / "data.csv",
                                      columns="broad")),
    **{f"cf_{name}": (f"Crazyflie {name}", InputSpec(
        imu=(DATA / "crazyflie_util" / name,), mocap=(DATA / "crazyflie_util" / name,)))
       for name in ("cfBolt-log00", "0425-traj1", "0422-log00")},
}


PX4_LOGS = ("sample.ulg", "sample_log_small.ulg")

SECTIONS = ("real_data_study", "real_data_px4")


def _cli(*args: str, cwd: Path | None = None) -> tuple[int, str]:
    """``python -m mocap_calib ARGS`` as a user runs it (in ``cwd``): exit code and the last
    stderr line."""
    repo = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [repo, *filter(None, [os.environ.get("PYTHONPATH")])])}
    p = subprocess.run([sys.executable, "-m", "mocap_calib", *args], capture_output=True,
                       text=True, check=False, cwd=cwd, env=env)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    return p.returncode, lines[-1] if lines else ""


def px4_logs() -> list[dict]:
    """Per PX4 log: calibrate (exit, refusal line) and allan on its IMU (exit, the noise
    densities or the refusal line)."""
    import yaml

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in PX4_LOGS:  # run in the logs' folder: the lines name the file alone
            here = DATA / "px4"
            code, line = _cli("calibrate", "--imu", name, "--mocap", name, "--out",
                              f"{tmp}/c.yaml", "-q", cwd=here)
            rec: dict = {"recording": f"PX4 {name}", "calibrate": {"exit": code, "line": line}}
            noise = Path(tmp) / f"{name}.yaml"
            code, line = _cli("allan", "--imu", name, "--out", str(noise), "-q", cwd=here)
            rec["allan"] = {"exit": code, "line": line}
            if code == 0:
                d = yaml.safe_load(noise.read_text())
                rec["allan"].update({k: d.get(k) for k in (
                    "gyroscope_noise_density", "accelerometer_noise_density",
                    "gyroscope_random_walk", "accelerometer_random_walk")})
            out.append(rec)
    return out


def px4_summary(reports: list[dict]) -> str:
    """One block per PX4 log: what calibrate and allan said."""
    lines = []
    for rep in reports:
        c, a = rep["calibrate"], rep["allan"]
        lines.append(f"{rep['recording']}: calibrate exit {c['exit']}: {c['line']}")
        what = (f"gyro N {a['gyroscope_noise_density']:.3g}, accel N "
                f"{a['accelerometer_noise_density']:.3g}" if a["exit"] == 0 else a["line"])
        lines.append(f"{rep['recording']}: allan exit {a['exit']}: {what}")
    return "\n".join(lines)


def run(session, opts: CalibrationOptions, start: float | None = None,
        end: float | None = None) -> dict:
    """One calibration (of the part from ``start`` to ``end`` s); a refusal is recorded with
    its exit code and message."""
    from mocap_calib.core.diagnosis.auto import calibrate_auto
    from mocap_calib.core.pipeline.calibrate import Recording, calibrate
    from mocap_calib.core.prepare.crop import crop_session

    t0 = time.perf_counter()
    try:
        imu, mocap = crop_session(session.imu, session.mocap, start, end, opts.time_offset)
        r = (calibrate_auto([Recording(imu, mocap)], opts) if opts.model.auto
             else calibrate(imu, mocap, opts))
    except CalibrationError as err:
        return {"exit": err.exit_code, "error": str(err), "seconds": time.perf_counter() - t0}
    out = {"exit": 0, "seconds": time.perf_counter() - t0, "notes": r.notes}
    out["R"] = None if r.rotation_wxyz is None else so3.quat_to_rotmat(r.rotation_wxyz)
    out["sR"] = r.sigma_rotation
    out["p"] = r.translation
    out["sp"] = r.sigma_translation
    out["td"] = r.time_offset
    out["std"] = r.sigma_time_offset
    out["g"] = r.gravity_in_mocap
    out["ba"] = r.accel_bias
    out["bg"] = r.gyro_bias
    out["result"] = r
    return out


def reference(key: str) -> tuple[np.ndarray, np.ndarray | None]:
    """R_MI (and p_MI) to compare with: what EuRoC's own ground truth implies
    (scripts/euroc_reference.py); identity elsewhere: BROAD's optical data were rotated into
    the IMU frame by the dataset's authors, and the Crazyflie's firmware reports its IMU in the
    body frame (no lever-arm reference for either)."""
    if key != "euroc":
        return np.eye(3), None
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from euroc_reference import gt_implied

    gt = gt_implied(DATA / "euroc_V2_03_difficult" / "mav0")
    return gt["R_MI"], gt["p_MI"]


def z_pair(a: dict, b: dict) -> dict[str, float]:
    """Largest per-axis |difference| / combined sigma of two runs."""
    z = {}
    if a.get("R") is not None and b.get("R") is not None:
        d = so3.log(a["R"].T @ b["R"])
        z["R_MI"] = float(np.max(np.abs(d) / np.hypot(a["sR"], b["sR"])))
    if a.get("p") is not None and b.get("p") is not None:
        z["p_MI"] = float(np.max(np.abs(a["p"] - b["p"]) / np.hypot(a["sp"], b["sp"])))
    if a.get("td") is not None and b.get("td") is not None:
        z["t_d"] = abs(a["td"] - b["td"]) / float(np.hypot(a["std"], b["std"]))
    return z


def moved(base: dict, other: dict) -> dict[str, float]:
    """How far a run moved from the base run, in the base run's sigmas (largest axis)."""
    z = {}
    if base.get("R") is not None and other.get("R") is not None:
        z["R_MI"] = float(np.max(np.abs(so3.log(base["R"].T @ other["R"])) / base["sR"]))
    if base.get("p") is not None and other.get("p") is not None:
        z["p_MI"] = float(np.max(np.abs(other["p"] - base["p"]) / base["sp"]))
    if base.get("td") is not None and other.get("td") is not None:
        z["t_d"] = abs(other["td"] - base["td"]) / base["std"]
    return z


def describe(key: str, r: dict, ref: tuple[np.ndarray, np.ndarray | None]) -> dict:
    if r["exit"] != 0:
        return {"exit": r["exit"], "error": r["error"], "seconds": round(r["seconds"], 1)}
    R_ref, p_ref = ref
    out = {"exit": 0, "seconds": round(r["seconds"], 1)}
    if r["R"] is not None:
        out["R_MI_vs_ref_deg"] = float(np.degrees(np.linalg.norm(so3.log(R_ref.T @ r["R"]))))
        out["sigma_R_deg"] = np.degrees(r["sR"]).round(4).tolist()
    if r["p"] is not None:
        out["p_MI_mm"] = (1e3 * r["p"]).round(2).tolist()
        out["sigma_p_mm"] = (1e3 * r["sp"]).round(3).tolist()
        if p_ref is not None:
            out["p_MI_vs_ref_mm"] = (1e3 * (r["p"] - p_ref)).round(2).tolist()
    if r["td"] is not None:
        out["t_d_ms"] = round(1e3 * r["td"], 3)
        out["sigma_t_d_ms"] = round(1e3 * r["std"], 4)
    if r["g"] is not None:
        out["tilt_deg"] = float(np.degrees(np.arccos(min(1.0, abs(r["g"][2])))))
    if r["ba"] is not None:
        out["accel_bias"] = np.round(r["ba"], 4).tolist()
    d = r["result"].to_dict()  # the result file's form
    for section in ("consistency", "sensitivity", "plausibility", "clock",
                    "noise_identification"):
        if d.get(section):
            out[section] = d[section]
    out.get("consistency", {}).pop("segments", None)
    return out


def study(key: str, thirds: bool, sensitivity: bool, fulls: dict | None = None) -> dict:
    label, spec = RECORDINGS[key]
    session = load_session(spec)
    noise = NoiseSpec().resolve(session.sensor_noise)
    opts = CalibrationOptions(noise=noise)
    full = run(session, opts)
    if fulls is not None:
        fulls[key] = full
    ref = reference(key)
    rep: dict = {"recording": label, "full": describe(key, full, ref)}
    if full["exit"] == 0:  # the result's own checks: thirds, noise models, effects shown
        r = full["result"].to_dict()  # the result file's form
        rep["own"] = {"thirds_max_z": r["consistency"].get("max_pairwise_z"),
                      "moved_sigmas": r["sensitivity"].get("moved_sigmas"),
                      "mocap_model": r["sensitivity"].get("mocap_noise_model"),
                      "effects_shown": r["effect_tests"].get("shown"),
                      "sigma_factor": r["consistency"].get("sigma_factor", {}),
                      "consistency_factor": {k: v["consistency_factor"]
                                             for k, v in r["uncertainty"].items()}}
    dur = session.imu.duration
    if thirds:
        parts = [run(session, opts, k * dur / 3, (k + 1) * dur / 3)
                 for k in range(3)]
        rep["thirds"] = [describe(key, p, ref) for p in parts]
        ok = [p for p in parts if p["exit"] == 0]
        zs = [z_pair(a, b) for a, b in itertools.combinations(ok, 2)]
        rep["thirds_max_z"] = {k: round(max(z[k] for z in zs), 2)
                               for k in ("R_MI", "p_MI", "t_d") if zs and all(k in z for z in zs)}
        if len(ok) > 1:  # the thirds' largest differences in units (the C++ peer's measure)
            rep["thirds_max_diff"] = {
                "R_MI_deg": round(max(float(np.degrees(np.linalg.norm(so3.log(a["R"].T @ b["R"]))))
                                      for a, b in itertools.combinations(ok, 2)), 3),
                "p_MI_mm": round(max(float(1e3 * np.linalg.norm(a["p"] - b["p"]))
                                     for a, b in itertools.combinations(ok, 2)), 2)}
    if sensitivity and full["exit"] == 0:
        sens = {}
        for f in (3.0, 1.0 / 3.0):
            o = run(session, replace(opts, noise=noise.imu_scaled(f)))
            sens[f"x{f:.3g}"] = ({k: round(v, 2) for k, v in moved(full, o).items()}
                                 if o["exit"] == 0 else {"exit": o["exit"], "error": o["error"]})
        rep["noise_sensitivity_sigmas"] = sens
    return rep


def trials_agree(fulls: dict[str, dict]) -> dict[str, dict[str, float]]:
    """The BROAD trials are one IMU on one rigid body: R_MI and p_MI of every pair, largest
    |difference| / combined sigma."""
    out = {}
    for a, b in itertools.combinations(sorted(fulls), 2):
        if fulls[a]["exit"] == 0 and fulls[b]["exit"] == 0:
            z = z_pair(fulls[a], fulls[b])
            out[f"{a}-{b}"] = {k: round(v, 2) for k, v in z.items() if k != "t_d"}
    return out


def summary(reports: list[dict]) -> str:
    """One line per recording: the figures of docs/validation.md's real-data table."""
    lines = ["recording    exit  R_MI vs ref  t_d (ms)            thirds max z (R, p, t_d)"
             "   moved sigmas x3 / x1/3 (R, p, t_d)"]
    for rep in reports:
        f = rep["full"]
        z = rep.get("thirds_max_z", {})
        zs = ", ".join(f"{z.get(k, float('nan')):.2f}" for k in ("R_MI", "p_MI", "t_d"))
        sens = rep.get("noise_sensitivity_sigmas", {})
        mv = " / ".join(", ".join(f"{s.get(k, float('nan')):.2f}" for k in ("R_MI", "p_MI", "t_d"))
                        if "exit" not in s else f"exit {s['exit']}" for s in sens.values())
        if f["exit"] != 0:
            lines.append(f"{rep['recording']:<12} {f['exit']:>4}  {f['error'][:90]}")
            continue
        lines.append(f"{rep['recording']:<12} {f['exit']:>4}"
                     f"  {f.get('R_MI_vs_ref_deg', float('nan')):8.2f} deg"
                     f"  {f.get('t_d_ms', 0):9.2f} +- {f.get('sigma_t_d_ms', 0):.2f}"
                     f"   {zs:<24}   {mv}")
    return "\n".join(lines)


def _three(x, fmt: str = ".1f") -> str:
    return ", ".join(format(v, fmt) for v in x)


def _row(rep: dict) -> list[str]:
    """One recording's row of the table."""
    f = rep["full"]
    if f["exit"] != 0:
        return [rep["recording"], f"exit {f['exit']}: {f['error']}", *["-"] * 6,
                f"{f['seconds']:.1f}"]
    sR = f["sigma_R_deg"]
    d = f.get("p_MI_vs_ref_mm")
    own = rep.get("own", {})
    z, fac = own.get("thirds_max_z") or {}, own.get("sigma_factor") or {}
    own_z = ", ".join(f"{z[k]:.1f}" + (f" (sigma x{fac[k]:.2f})" if fac.get(k, 1.0) > 1.0
                                       else "") for k in ("R_MI", "p_MI", "t_d") if k in z)
    tz, tm = rep.get("thirds_max_z", {}), rep.get("thirds_max_diff", {})
    thirds = (", ".join(f"{tz[k]:.1f}" for k in ("R_MI", "p_MI", "t_d") if k in tz)
              + (f"; {tm['R_MI_deg']:.2f} deg, {tm['p_MI_mm']:.1f} mm" if tm else ""))
    return [rep["recording"], f"{f['R_MI_vs_ref_deg']:.2f} deg (sigma {min(sR):.2f}-{max(sR):.2f})",
            f"{_three(f['p_MI_mm'])} +- {_three(f['sigma_p_mm'])}",
            "-" if d is None else f"{_three(d)} ({float(np.linalg.norm(d)):.1f})",
            f"{f['t_d_ms']:.2f} +- {f['sigma_t_d_ms']:.2f}", own_z, thirds,
            ", ".join(own.get("effects_shown") or []) or "none", f"{f['seconds']:.1f}"]


def _noise_line(reports: list[dict], limit: float = 1.0) -> str:
    """How far the answers move with the noise densities x3 and x1/3 (independent reruns)."""
    over = []
    for rep in reports:
        for scale, moved_by in rep.get("noise_sensitivity_sigmas", {}).items():
            for k, v in moved_by.items():
                if k != "exit" and k != "error" and v > limit:
                    over.append(f"`{k}` at {scale.replace('x0.333', 'x1/3')} on "
                                f"{rep['recording']} ({v:.2f} sigma)")
    return (f"Noise densities x3 and x1/3 (independent reruns) move every answer by at most "
            f"{limit:.1f} sigma" + (", except " + "; ".join(over) if over else "") + ".\n")


def markdown(reports: list[dict], pairs: dict[str, dict[str, float]]) -> str:
    """Section real_data_study: the recordings' table, the noise scalings, the BROAD pairs."""
    recs = [r for r in reports if "full" in r]
    out = (provenance("real_data_study.py") + "\n"
           + table(["recording", "`R_MI` vs reference", "`p_MI` (mm) +- sigma",
                    "`p_MI` vs reference (mm)", "`t_d` (ms)", "own check: thirds z (R, p, t_d)",
                    "independent thirds: max z (R, p, t_d); max difference",
                    "effects the data show", "calibration (s)"], [_row(r) for r in recs])
           + "\n" + _noise_line(recs))
    if pairs:
        out += "\n" + table(["BROAD trials", "`R_MI`: max \\|difference\\| / combined sigma",
                             "`p_MI`"],
                            [[k.replace("broad", ""), f"{v.get('R_MI', float('nan')):.1f}",
                              f"{v.get('p_MI', float('nan')):.1f}"] for k, v in pairs.items()])
    return out


def readme_markdown(reports: list[dict]) -> str:
    """Section real_data of the README: per recording the exit code, the answer with its
    sigmas and the wall time; a refusal's cause to its first clause."""
    rows = []
    for rep in (r for r in reports if "full" in r):
        f = rep["full"]
        if f["exit"] != 0:
            cause = re.split(r" \(|: ", f["error"].removeprefix("error: "), maxsplit=1)[0]
            rows.append([rep["recording"], str(f["exit"]), cause, "", "", f"{f['seconds']:.0f}"])
            continue
        sR = np.asarray(f["sigma_R_deg"])
        rows.append([rep["recording"], "0",
                     f"{f['R_MI_vs_ref_deg']:.2f} (sigma {sR.min():.2f}-{sR.max():.2f})",
                     f"{_three(f['p_MI_mm'])} +- {_three(f['sigma_p_mm'])}",
                     f"{f['t_d_ms']:.2f} +- {f['sigma_t_d_ms']:.2f}", f"{f['seconds']:.0f}"])
    # The README names the command, not the commit (docs/validation.md carries that).
    return f"Measured with `{command_line('real_data_study.py')}`.\n" + table(
        ["recording", "exit", "`R_MI` from the reference (deg), or the refusal", "`p_MI` (mm)",
         "`t_d` (ms)", "s"], rows)


def px4_markdown(px4: list[dict]) -> str:
    """Section real_data_px4: what calibrate and allan say on the PX4 logs."""
    lines = [provenance("real_data_study.py").rstrip("\n"), "", "```"]
    for rep in px4:
        for cmd in ("calibrate", "allan"):
            r = rep[cmd]
            lines.append(f"{rep['recording']}, {cmd}: exit {r['exit']}")
            lines.append(r["line"] if r["exit"] else
                         f"gyro N {r['gyroscope_noise_density']:.3g}, accel N "
                         f"{r['accelerometer_noise_density']:.3g}")
    return "\n".join([*lines, "```"]) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", type=Path)
    ap.add_argument("--only", default=",".join([*RECORDINGS, "px4"]))
    ap.add_argument("--no-thirds", action="store_true")
    ap.add_argument("--no-sensitivity", action="store_true")
    ap.add_argument("--readme", type=Path, default=ROOT / "README.md",
                    help="with --write-doc, the README whose real_data section is rewritten")
    add_doc_options(ap)
    a = ap.parse_args()
    if not DATA.is_dir():
        print(f"error: {DATA}: no such folder; the recordings live in ../shared/data next to "
              "the repository", file=sys.stderr)
        sys.exit(2)
    keys = a.only.split(",")
    full = set(RECORDINGS) <= set(keys) and not a.no_thirds and not a.no_sensitivity
    check(a, [*(["real_data_study"] if full else []), *(["real_data_px4"] if "px4" in keys
                                                         else [])])
    reports = []
    fulls: dict[str, dict] = {}
    for key in (k for k in keys if k != "px4"):
        rep = study(key, not a.no_thirds, not a.no_sensitivity, fulls)
        print(json.dumps(rep, indent=1), flush=True)
        reports.append(rep)
    print(summary(reports))
    px4: list[dict] = []
    if "px4" in keys:
        px4 = px4_logs()
        print(px4_summary(px4))
    broad = {k: v for k, v in fulls.items() if k.startswith("broad")}
    pairs = trials_agree(broad) if len(broad) > 1 else {}
    if pairs:
        print("BROAD trials pairwise max z (R_MI, p_MI):", json.dumps(pairs))
    sections = {}
    if reports:
        sections["real_data_study"] = markdown(reports, pairs)
    if px4:
        sections["real_data_px4"] = px4_markdown(px4)
    for text in sections.values():
        print(text)
    if a.json:
        a.json.write_text(json.dumps([*reports, *px4, {"broad_pairs_max_z": pairs}], indent=1,
                                     default=str))
    # The recordings' table is written only from a full run (a partial one would drop rows).
    write(a, {k: v for k, v in sections.items() if k != "real_data_study" or full})
    if a.write_doc and full and reports:
        write(argparse.Namespace(write_doc=True, doc=a.readme),
              {"real_data": readme_markdown(reports)})


if __name__ == "__main__":
    main()
