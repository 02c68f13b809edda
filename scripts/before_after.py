"""Before/after comparison of calibration results across a code change.

``run`` calibrates a fixed set of sessions through the command line (EuRoC V2_03, BROAD 15/21/27
and the Crazyflie flights from ``../shared/data``, and simulated sessions written once to
``--sessions``) and keeps every result YAML in OUT; ``compare`` reads two such folders and
prints, per session and parameter, the largest difference, the largest |difference| / sigma
(the "after" sigma) and the range of the sigmas' ratio after / before. A refactor must give
identical results; a speed change must stay within 0.1 sigma.

Usage:
    python scripts/before_after.py run OUT [--sessions DIR] [--only euroc,sim1]
    python scripts/before_after.py compare BEFORE AFTER [--limit 0.1]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
CLI = [sys.executable, "-m", "mocap_calib"]

#: Simulated sessions: (name, simulate arguments). Rough on purpose: correlated mocap noise,
#: bias walk (on by default), dropouts and outliers, a clock offset.
SIMULATED = {
    "sim1": ["--seed", "11", "--duration", "60", "-e", "time_offset=0.004"],
    "sim2": ["--seed", "12", "--duration", "90", "-e", "time_offset=-0.012",
             "--mocap-noise-corr", "0.3", "-e", "mocap_dropouts=3"],
    "sim3": ["--seed", "13", "--duration", "60", "-e", "time_offset=0.002",
             "-e", "mocap_outliers=4", "-e", "accel_delay=0.003"],
}


def sessions(sim_dir: Path) -> dict[str, list[str]]:
    """Name -> calibrate input arguments."""
    out = {
        "euroc": [str(DATA / "euroc_V2_03_difficult" / "mav0")],
    }
    for trial in ("15_undisturbed_fast_translation_A", "21_undisturbed_fast_combined",
                  "27_disturbed_phone_vibration_B"):
        csv = str(DATA / f"broad_{trial}" / "data.csv")
        out[f"broad{trial[:2]}"] = ["--imu", csv, "--mocap", csv, "--columns", "broad"]
    for flight in ("cfBolt-log00", "0425-traj1", "0422-log00"):
        log = str(DATA / "crazyflie_util" / flight)
        out[f"cf_{flight}"] = ["--imu", log, "--mocap", log]
    for name in SIMULATED:
        out[name] = [str(sim_dir / name)]
    return out


def simulate(sim_dir: Path) -> None:
    for name, args in SIMULATED.items():
        if not (sim_dir / name / "truth.yaml").exists():
            subprocess.run([*CLI, "simulate", str(sim_dir / name), *args], check=True,
                           capture_output=True)


def run(out: Path, sim_dir: Path, only: list[str] | None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    simulate(sim_dir)
    for name, args in sessions(sim_dir).items():
        if only and name not in only:
            continue
        t0 = time.perf_counter()
        p = subprocess.run([*CLI, "calibrate", *args, "--out", str(out / f"{name}.yaml"),
                            "--quiet"], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        (out / f"{name}.log").write_text(p.stdout + p.stderr)
        print(f"{name}: exit {p.returncode}, {wall:.1f} s", flush=True)
    meta = {"commit": subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"],
                                     capture_output=True, text=True).stdout.strip()}
    (out / "meta.json").write_text(json.dumps(meta))


#: Result keys compared, with their sigma keys.
KEYS = ("gyro_bias", "accel_bias", "time_offset", "gravity_in_mocap")


def _flat(d: dict) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Parameter -> (value, sigma) from a result YAML."""
    sig = d.get("sigma", {}) or {}
    out = {}
    for k in KEYS:
        if d.get(k) is not None:
            s = sig.get(k)
            out[k] = (np.atleast_1d(np.asarray(d[k], float)),
                      None if s is None else np.atleast_1d(np.asarray(s, float)))
    T = d.get("T_marker_imu") or {}
    for k, tk in (("rotation", "rotation_wxyz"), ("translation", "translation")):
        v = T.get(tk, T.get(k))  # the result files write the rotation as rotation_wxyz
        if v is not None:
            s = sig.get(k)
            out[k] = (np.asarray(v, float), None if s is None else np.asarray(s, float))
    for name, e in (d.get("effects") or {}).items():
        for pk, v in e.items():
            if pk in ("sigma", "ppm") or v is None or isinstance(v, dict):
                continue
            s = (e.get("sigma") or None)
            out[f"{name}.{pk}"] = (np.atleast_1d(np.asarray(v, float)).ravel(),
                                   None if s is None or isinstance(s, dict)
                                   else np.atleast_1d(np.asarray(s, float)).ravel())
    return out


def compare(before: Path, after: Path, limit: float) -> int:
    worst = 0.0
    for fb in sorted(before.glob("*.yaml")):
        fa = after / fb.name
        if not fa.exists():
            print(f"{fb.stem}: missing after")
            worst = np.inf
            continue
        b, a = _flat(yaml.safe_load(fb.read_text())), _flat(yaml.safe_load(fa.read_text()))
        print(f"{fb.stem}:")
        for k in sorted(set(b) | set(a)):
            if k not in a or k not in b:
                print(f"  {k:<28} only {'before' if k in b else 'after'}")
                worst = np.inf
                continue
            vb, sb = b[k]
            va, sa = a[k]
            if k == "rotation":  # quaternions: the angle between them (atan2: exact near 0)
                qa, qb = va / np.linalg.norm(va), vb / np.linalg.norm(vb)
                w = float(np.dot(qa, qb))
                vec = qb[0] * qa[1:] - qa[0] * qb[1:] - np.cross(qb[1:], qa[1:])
                diff = np.array([2.0 * np.arctan2(np.linalg.norm(vec), abs(w))])
                z = diff / max(float(np.min(sa)), 1e-300) if sa is not None else None
            else:
                diff = np.abs(va - vb)
                z = diff / np.maximum(sa, 1e-300) if sa is not None and sa.shape == diff.shape \
                    else None
            zmax = float(np.max(z)) if z is not None else float("nan")
            if z is not None:
                worst = max(worst, zmax)
            ratio = ""
            if sa is not None and sb is not None and sa.shape == sb.shape:
                r = sa / np.maximum(sb, 1e-300)
                ratio = f"   sigma after/before {float(np.min(r)):.3g}-{float(np.max(r)):.3g}"
            print(f"  {k:<28} max |diff| {float(np.max(diff)):.3g}   max |diff|/sigma "
                  f"{zmax:.3g}{ratio}")
    print(f"largest |diff|/sigma: {worst:.3g} (limit {limit})")
    return 0 if worst <= limit else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--sessions", type=Path, default=Path("/tmp/mocap_calib_sessions"))
    r.add_argument("--only", type=lambda s: s.split(","), default=None)
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--limit", type=float, default=0.0)
    args = ap.parse_args()
    if args.cmd == "run":
        run(args.out, args.sessions, args.only)
        return 0
    return compare(args.before, args.after, args.limit)


if __name__ == "__main__":
    sys.exit(main())
