"""Benchmark against a peer calibrator (mocap2gt) on simulated flights with rotor vibration.

For each seed a flight is simulated with the ``flying`` preset (``mocap_calib/sim/presets.py``:
accelerometer white noise 10x its data sheet's, rotor vibration 2 m/s^2 at 95-145 Hz with its
harmonic aliased by the 200 Hz IMU, correlated mocap noise, 0.2 deg Vicon attitude noise, bias
walks, a 5 ms clock offset) and written in the EuRoC layout. ``mocap-calib calibrate`` runs on
it with its default options, and the peer through the command given with ``--peer``; both are
given the data sheet's noise (the simulator's ``NoiseModel`` defaults, which are also
``calibrate``'s defaults). Each tool runs as its own process, one after the other.

The peer command is called as ``PEER --imu IMU.csv --mocap MOCAP.csv --out RESULT.yaml
--gyro-nd X --accel-nd X --gyro-rw X --accel-rw X --mocap-pos-sigma M --mocap-rot-sigma RAD``
and must write a YAML with ``R_MI`` (quaternion wxyz, T_MI's rotation), ``p_MI`` (m) and
``time_offset`` (s, mocap-calib's sign: an IMU sample stamped t was measured at mocap time
t + time_offset); ``run: {wall_s}`` is shown when present (the peer's own timing). mocap2gt's
wrapper (``run_mocap2gt.sh`` where it was built) has this interface. Without ``--peer`` only
mocap-calib runs, and the table says so.

The peer does not change with mocap-calib: ``--peer-from DIR`` takes its result for a flight from
an earlier run's ``--out`` folder when that folder holds the same flight (its IMU and mocap
files byte for byte identical to the new simulation's) and the peer's ``peer.yaml``; a flight
without one runs the peer (``--peer``). Reused results have no wall time, and the table names
how many were reused.

Printed: per seed and as means, the R_MI (deg), p_MI (mm) and t_d (ms) errors of both tools
side by side and their wall times; mocap-calib's |err|/sigma (largest axis) per parameter and
seed, and its maximum over the seeds.

Usage: python scripts/bench_peer.py [--seeds 4] [--first-seed 1] [--duration 90]
                                    [--peer 'CMD ...'] [--peer-from DIR ...] [--out DIR]
                                    [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from _doc_section import add_doc_options, check, provenance, table, write

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.io.yaml_io import load_result
from mocap_calib.report.compare import compare
from mocap_calib.workflows.simulate import simulate_to_folder

#: The section of docs/validation.md this script writes.
SECTIONS = ("bench_peer",)

CLI = [sys.executable, "-m", "mocap_calib"]
METRICS = (("R_MI", "deg"), ("p_MI", "mm"), ("t_d", "ms"))
#: mocap-calib's parameters whose |err|/sigma is shown (report.compare's rows).
Z_PARAMS = ("R_MI", "p_MI", "gyro_bias", "accel_bias", "gravity_in_mocap", "time_offset")


@dataclass
class Run:
    """One tool on one flight: its errors against the truth, wall time, and what went wrong."""

    tool: str
    seed: int
    errors: dict[str, float] = field(default_factory=dict)
    wall_s: float = float("nan")  # the process, as this script timed it
    own_wall_s: float | None = None  # the tool's own timing, when it reports one
    z: dict[str, float] = field(default_factory=dict)
    failure: str = ""
    reused: bool = False  # the peer's result taken from an earlier run of the same flight


def errors(truth: dict[str, Any], rotation_wxyz: Any, translation: Any,
           time_offset: float) -> dict[str, float]:
    """The same metrics for every tool: rotation angle (deg), lever-arm distance (mm),
    |clock offset error| (ms)."""
    R_true = so3.quat_to_rotmat(np.asarray(truth["T_marker_imu"]["rotation_wxyz"], float))
    R_est = so3.quat_to_rotmat(np.asarray(rotation_wxyz, float))
    dp = np.asarray(translation, float) - np.asarray(truth["T_marker_imu"]["translation"])
    return {"R_MI": float(np.degrees(np.linalg.norm(so3.log(R_true.T @ R_est)))),
            "p_MI": float(1e3 * np.linalg.norm(dp)),
            "t_d": float(1e3 * abs(float(time_offset) - truth["time_offset"]))}


def _tail(proc: subprocess.CompletedProcess[str]) -> str:
    lines = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
    return f"exit {proc.returncode}: {lines[-1] if lines else 'no output'}"


def run_ours(session: Path, seed: int, truth: dict[str, Any]) -> Run:
    out = session / "mocap_calib.yaml"
    t0 = time.perf_counter()
    proc = subprocess.run([*CLI, "calibrate", str(session / "mav0"), "--out", str(out)],
                          capture_output=True, text=True)
    run = Run("mocap-calib", seed, wall_s=time.perf_counter() - t0)
    if proc.returncode != 0:
        run.failure = _tail(proc)
    if not out.exists():
        return run
    d = yaml.safe_load(out.read_text())
    run.errors = errors(truth, d["T_marker_imu"]["rotation_wxyz"],
                        d["T_marker_imu"]["translation"], d["time_offset"])
    rows = compare(load_result(out), load_result(session / "truth.yaml"))
    run.z = {r.name: r.z for r in rows if r.z is not None}
    return run


def peer_noise_args(noise: NoiseModel) -> list[str]:
    return ["--gyro-nd", repr(noise.gyroscope_noise_density),
            "--accel-nd", repr(noise.accelerometer_noise_density),
            "--gyro-rw", repr(noise.gyroscope_random_walk),
            "--accel-rw", repr(noise.accelerometer_random_walk),
            "--mocap-pos-sigma", repr(noise.mocap_position_sigma),
            "--mocap-rot-sigma", repr(noise.mocap_rotation_sigma)]


def run_peer(peer: list[str], session: Path, seed: int, truth: dict[str, Any]) -> Run:
    out = session / "peer.yaml"
    out.unlink(missing_ok=True)  # the script's own output of an earlier run
    mav0 = session / "mav0"
    cmd = [*peer, "--imu", str(mav0 / "imu0" / "data.csv"), "--mocap",
           str(mav0 / "vicon0" / "data.csv"), "--out", str(out), *peer_noise_args(NoiseModel())]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    run = Run("peer", seed, wall_s=time.perf_counter() - t0)
    if proc.returncode != 0:
        run.failure = _tail(proc)
    if not out.exists():
        run.failure = run.failure or "no result written"
        return run
    d = yaml.safe_load(out.read_text())
    run.errors = errors(truth, d["R_MI"], d["p_MI"], d["time_offset"])
    run.own_wall_s = (d.get("run") or {}).get("wall_s")
    return run


#: The flight's input files that must match for a peer result to be reused.
FLIGHT_FILES = ("mav0/imu0/data.csv", "mav0/vicon0/data.csv")


def reused_peer(earlier: list[Path], session: Path, seed: int,
                truth: dict[str, Any]) -> Run | None:
    """The peer's result for this flight from an earlier run's folder, when one holds the same
    flight (byte-identical input files) and the peer's result; else None."""
    for root in earlier:
        old = root / session.name
        if not (old / "peer.yaml").exists() or not all(
                (old / f).exists() and (old / f).read_bytes() == (session / f).read_bytes()
                for f in FLIGHT_FILES):
            continue
        d = yaml.safe_load((old / "peer.yaml").read_text())
        run = Run("peer", seed, reused=True)
        run.errors = errors(truth, d["R_MI"], d["p_MI"], d["time_offset"])
        run.own_wall_s = (d.get("run") or {}).get("wall_s")
        return run
    return None


def _fmt(x: float | None, width: int = 10, digits: int = 3) -> str:
    return f"{'-':>{width}}" if x is None or not np.isfinite(x) else f"{x:>{width}.{digits}f}"


def print_table(runs: list[Run], seeds: list[int], peer_name: str | None) -> None:
    tools = ["mocap-calib", *(["peer"] if peer_name else [])]
    label = {"mocap-calib": "mocap-calib", "peer": peer_name or ""}
    head = "".join(f"{m + ' ' + u:>11}" for m, u in METRICS)
    print(f"{'seed':<6}{'tool':<14}{head}{'wall s':>10}{'own s':>8}  note")
    for seed in seeds:
        for tool in tools:
            r = next(x for x in runs if x.seed == seed and x.tool == tool)
            vals = "".join(_fmt(r.errors.get(m), 11) for m, _ in METRICS)
            print(f"{seed:<6}{label[tool]:<14}{vals}{_fmt(r.wall_s, 10, 1)}"
                  f"{_fmt(r.own_wall_s, 8, 1)}  {r.failure}")
    print("mean over the flights each tool calibrated:")
    for tool in tools:
        done = [r for r in runs if r.tool == tool and r.errors]
        means = "".join(_fmt(float(np.mean([r.errors[m] for r in done])) if done else None, 11)
                        for m, _ in METRICS)
        walls = [r.wall_s for r in done if not r.reused]
        wall = float(np.mean(walls)) if walls else None
        print(f"{'mean':<6}{label[tool]:<14}{means}{_fmt(wall, 10, 1)}"
              f"{'':>8}  {len(done)}/{len(seeds)} flights")
    if not peer_name:
        print("(no --peer given: the peer was not run)")
    ours = [r for r in runs if r.tool == "mocap-calib" and r.z]
    print("\nmocap-calib |err|/sigma (largest axis) per parameter:")
    print(f"{'parameter':<18}" + "".join(f"{'seed ' + str(r.seed):>10}" for r in ours)
          + f"{'max':>10}")
    for k in Z_PARAMS:
        zs = [r.z.get(k) for r in ours]
        finite = [z for z in zs if z is not None]
        print(f"{k:<18}" + "".join(_fmt(z, 10, 2) for z in zs)
              + _fmt(max(finite) if finite else None, 10, 2))


def markdown(runs: list[Run], seeds: list[int], duration: float, peer_name: str | None) -> str:
    """Section bench_peer: both tools' mean errors side by side, and our largest |err|/sigma."""
    tools = ["mocap-calib", *(["peer"] if peer_name else [])]
    rows = []
    for tool in tools:
        done = [r for r in runs if r.tool == tool and r.errors]
        rows.append([peer_name if tool == "peer" else tool,
                     *(f"{np.mean([r.errors[m] for r in done]):.3f}" if done else "-"
                       for m, _ in METRICS),
                     _mean_wall(done), f"{len(done)}/{len(seeds)}"])
    ours = [r for r in runs if r.tool == "mocap-calib" and r.z]
    worst = {k: max((r.z[k] for r in ours if k in r.z), default=float("nan")) for k in Z_PARAMS}
    n_reused = sum(r.reused for r in runs)
    reused = (f"\n{peer_name}'s results for {n_reused} of the flights are those of an earlier "
              "run of the same flights (byte-identical inputs; `--peer-from`); its wall time is "
              "over the flights it ran here (none: `-`).\n" if n_reused else "")
    return (provenance("bench_peer.py") + "\n"
            + f"{len(seeds)} simulated flights of {duration:g} s (`--preset flying`, seeds "
            f"{seeds[0]}-{seeds[-1]}), both tools given the data sheet's noise; mean errors "
            "against the simulator's truth:\n\n"
            + table(["tool", "`R_MI` (deg)", "`p_MI` (mm)", "`t_d` (ms)", "wall (s)",
                     "flights"], rows)
            + "\nmocap-calib's largest \\|err\\|/sigma over the flights: "
            + ", ".join(f"{k} {v:.2f}" for k, v in worst.items()) + ".\n" + reused)


def _mean_wall(done: list[Run]) -> str:
    walls = [r.wall_s for r in done if not r.reused]
    return f"{np.mean(walls):.1f}" if walls else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=90.0, help="s per flight")
    ap.add_argument("--peer", default=None,
                    help="the peer's command (see the module doc); absent: mocap-calib only")
    ap.add_argument("--peer-name", default="mocap2gt", help="the peer's name in the table")
    ap.add_argument("--peer-from", type=Path, nargs="*", default=[],
                    help="earlier runs' --out folders whose peer results are reused for the "
                         "same flights (see the module doc)")
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for the sessions and results (default: a temporary one)")
    ap.add_argument("--json", type=Path, default=None, help="also write every run here")
    add_doc_options(ap)
    a = ap.parse_args()
    check(a, list(SECTIONS))
    peer = shlex.split(a.peer) if a.peer else None
    peer_name = a.peer_name if peer or a.peer_from else None
    seeds = list(range(a.first_seed, a.first_seed + a.seeds))
    with tempfile.TemporaryDirectory() as tmp:
        root = a.out or Path(tmp)
        runs: list[Run] = []
        for seed in seeds:
            session = root / f"flying_{seed}"
            simulate_to_folder(session, seed=seed, duration=a.duration, preset="flying")
            truth = yaml.safe_load((session / "truth.yaml").read_text())
            runs.append(run_ours(session, seed, truth))
            old = reused_peer(a.peer_from, session, seed, truth)
            if old is not None:
                runs.append(old)
            elif peer:
                runs.append(run_peer(peer, session, seed, truth))
            elif a.peer_from:
                runs.append(Run("peer", seed, failure="not in --peer-from and no --peer"))
            print(f"seed {seed}: " + "; ".join(
                f"{r.tool} {'reused' if r.reused else f'{r.wall_s:.1f} s'} {r.failure}".strip()
                for r in runs[-2:]
                if r.seed == seed), flush=True)
    print(f"\nflying preset: {len(seeds)} flights of {a.duration:g} s (seeds {seeds[0]}-"
          f"{seeds[-1]}); both tools given the data sheet's noise (NoiseModel defaults); "
          "errors against the simulator's truth")
    print_table(runs, seeds, peer_name)
    if a.json:
        a.json.write_text(json.dumps([asdict(r) for r in runs], indent=1))
    md = markdown(runs, seeds, a.duration, peer_name)
    print(md)
    write(a, {"bench_peer": md})


if __name__ == "__main__":
    main()
