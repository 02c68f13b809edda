"""Before/after comparison of ``diagnose`` and ``calibrate --model auto`` across a code change.

``run`` diagnoses a fixed set of sessions through the command line (EuRoC V2_03, BROAD 15/21/27,
mocap2gt's 65 s session, two Crazyflie flights, and simulated sessions with hidden effects
written once to ``--sessions``), and calibrates each with ``--model auto``; it keeps every
report and result in OUT with each run's wall and CPU time (``os.wait4``). ``--repo`` runs
another checkout's code (the "before": e.g. ``git archive main | tar -x -C DIR``).
``compare`` reads two such folders and prints, per session, the effects each named, the
largest |difference| / sigma of the final estimates (the "after" sigma, as
``scripts/before_after.py`` compares them) and the times.

Usage:
    python scripts/diagnose_before_after.py run OUT [--repo DIR] [--only euroc,sim_delay]
        [--commands diagnose,auto]
    python scripts/diagnose_before_after.py compare BEFORE AFTER [--limit 0.1]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml
from _shared_data import DATA
from before_after import _flat as flat

REPO = Path(__file__).resolve().parents[1]
#: mocap2gt's real session (imu.csv, mocap.csv): ``peer/m2g_session`` beside ``shared``
#: (of this checkout or of the folders above it).
PEER = next((p / "peer" / "m2g_session" for p in (DATA.parents[1], *DATA.parents[1].parents)
             if (p / "peer" / "m2g_session").is_dir()), DATA.parents[1] / "peer" / "m2g_session")

#: Simulated sessions with hidden effects: (name, simulate arguments).
SIMULATED = {
    "sim_delay": ["--seed", "4", "--duration", "60", "-e", "time_offset=0.006",
                  "-e", "accel_delay=0.005"],
    "sim_gyro_sm": ["--seed", "601", "--duration", "90", "-e", "time_offset=0.004",
                    "-e", "gyro_scale_misalignment"],
    "sim_none": ["--seed", "600", "--duration", "90", "--mocap-noise-corr", "0.3"],
    "sim2min_delay": ["--seed", "21", "--duration", "120", "-e", "time_offset=0.003",
                      "-e", "accel_delay=0.004", "--mocap-noise-corr", "0.3"],
    "sim10": ["--seed", "7", "--duration", "600"],  # scripts/bench_models.py's
}


def sessions(sim_dir: Path) -> dict[str, list[str]]:
    """Name -> the commands' input arguments."""
    out = {"euroc": [str(DATA / "euroc_V2_03_difficult" / "mav0")]}
    for trial in ("15_undisturbed_fast_translation_A", "21_undisturbed_fast_combined",
                  "27_disturbed_phone_vibration_B"):
        csv = str(DATA / f"broad_{trial}" / "data.csv")
        out[f"broad{trial[:2]}"] = ["--imu", csv, "--mocap", csv, "--columns", "broad"]
    out["m2g"] = ["--imu", str(PEER / "imu.csv"), "--mocap", str(PEER / "mocap.csv")]
    for flight in ("cfBolt-log00", "0422-log00"):
        log = str(DATA / "crazyflie_util" / flight)
        out[f"cf_{flight}"] = ["--imu", log, "--mocap", log]
    for name in SIMULATED:
        out[name] = [str(sim_dir / name)]
    return out


def _cli(repo: Path, args: list[str]) -> tuple[int, float, float, str]:
    """Exit code, wall s, CPU s and stderr of one CLI run with ``repo``'s code."""
    env = {**os.environ, "PYTHONPATH": str(repo)}
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "mocap_calib", *args], cwd=repo, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    _, status, ru = os.wait4(proc.pid, 0)
    return (os.waitstatus_to_exitcode(status), time.perf_counter() - t0,
            ru.ru_utime + ru.ru_stime, err)


def run(out: Path, repo: Path, sim_dir: Path, only: list[str] | None,
        commands: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, args in SIMULATED.items():
        if (only is None or name in only) and not (sim_dir / name / "truth.yaml").exists():
            subprocess.run([sys.executable, "-m", "mocap_calib", "simulate", str(sim_dir / name),
                            *args], check=True, capture_output=True)
    times_file = out / "times.json"
    times = json.loads(times_file.read_text()) if times_file.exists() else {}
    for name, args in sessions(sim_dir).items():
        if only and name not in only:
            continue
        for cmd, extra in (("diagnose", ["diagnose"]), ("auto", ["calibrate"])):
            if cmd not in commands:
                continue
            target = out / f"{name}.{cmd}.yaml"
            more = ["--model", "auto"] if cmd == "auto" else []
            code, wall, cpu, err = _cli(repo, [*extra, *args, *more, "--out", str(target),
                                               "--quiet"])
            (out / f"{name}.{cmd}.log").write_text(err)
            times[f"{name}.{cmd}"] = {"exit": code, "wall_s": round(wall, 2),
                                      "cpu_s": round(cpu, 2)}
            times_file.write_text(json.dumps(times, indent=1))
            print(f"{name} {cmd}: exit {code}, {wall:.1f} s wall, {cpu:.1f} s CPU", flush=True)
    meta = {"commit": subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"],
                                     capture_output=True, text=True).stdout.strip(),
            "repo": str(repo)}
    (out / "meta.json").write_text(json.dumps(meta))


def _named(path: Path, cmd: str) -> str:
    """The effects a report or result names (its final model's, in a fixed order: the order
    they were found in is not compared; a diagnosis' unexplained residual too)."""
    if not path.exists():
        return "(missing)"
    d = yaml.safe_load(path.read_text())
    model = str(d["final_model"] if cmd == "diagnose" else d["model"]).split("+")
    named = "+".join([model[0], *sorted(model[1:])])
    return named + ("; unexplained" if cmd == "diagnose" and d.get("unexplained") else "")


def largest_z(before: dict, after: dict) -> float:
    """The largest |after - before| / (after's sigma) over the compared estimates (inf when
    one has an estimate the other lacks)."""
    b, a = flat(before), flat(after)
    worst = 0.0
    for k in set(b) | set(a):
        if k not in a or k not in b:
            return float("inf")
        (vb, _), (va, sa) = b[k], a[k]
        if sa is None or vb.shape != va.shape:
            continue
        if k == "rotation":  # quaternions: the angle between them
            qa, qb = va / np.linalg.norm(va), vb / np.linalg.norm(vb)
            vec = qb[0] * qa[1:] - qa[0] * qb[1:] - np.cross(qb[1:], qa[1:])
            diff = np.array([2.0 * np.arctan2(np.linalg.norm(vec), abs(float(qa @ qb)))])
            z = diff / max(float(np.min(sa)), 1e-300)
        elif sa.shape == va.shape:
            z = np.abs(va - vb) / np.maximum(sa, 1e-300)
        else:
            continue
        worst = max(worst, float(np.max(z)))
    return worst


def _final(path: Path, cmd: str) -> dict | None:
    if not path.exists():
        return None
    d = yaml.safe_load(path.read_text())
    return d["final_calibration"] if cmd == "diagnose" else d


def compare(before: Path, after: Path, limit: float) -> int:
    tb = json.loads((before / "times.json").read_text())
    ta = json.loads((after / "times.json").read_text())
    rows = ["| session | command | model before | model after | max abs(diff)/sigma | "
            "wall before / after (s) | CPU before / after (s) |", "|---" * 7 + "|"]
    bad = 0
    for key in sorted(tb):
        name, cmd = key.rsplit(".", 1)
        fb, fa = before / f"{name}.{cmd}.yaml", after / f"{name}.{cmd}.yaml"
        mb, ma = _named(fb, cmd), _named(fa, cmd)
        rb, ra = _final(fb, cmd), _final(fa, cmd)
        z = largest_z(rb, ra) if rb is not None and ra is not None else float("inf")
        if mb != ma or not z <= limit:
            bad += 1
        a = ta.get(key, {})
        rows.append(f"| {name} | {cmd} | {mb} | {ma} | {z:.3g} | "
                    f"{tb[key]['wall_s']:.1f} / {a.get('wall_s', float('nan')):.1f} | "
                    f"{tb[key]['cpu_s']:.1f} / {a.get('cpu_s', float('nan')):.1f} |")
    print("\n".join(rows))
    print(f"{bad} row(s) with another model or beyond {limit} sigma")
    return 0 if bad == 0 else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--repo", type=Path, default=REPO, help="the checkout whose code runs")
    r.add_argument("--sessions", type=Path, default=Path("/tmp/mocap_calib_diag_sessions"))
    r.add_argument("--only", type=lambda s: s.split(","), default=None)
    r.add_argument("--commands", type=lambda s: s.split(","), default=["diagnose", "auto"],
                   help="diagnose,auto (default both)")
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--limit", type=float, default=0.1)
    args = ap.parse_args()
    if args.cmd == "run":
        run(args.out, args.repo.resolve(), args.sessions, args.only, args.commands)
        return 0
    return compare(args.before, args.after, args.limit)


if __name__ == "__main__":
    sys.exit(main())
