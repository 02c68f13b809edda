"""Check that the rerun recording and the HTML report stay the same across a code change.

``solve`` calibrates (or diagnoses) a fixed set of sessions once and pickles what the command
computed (the result with its diagnostics, and what was read); ``write`` runs the commands'
own writing (``calibrate``/``diagnose`` with ``--rrd`` and ``--html``) on those pickles with the
code on ``PYTHONPATH``, so that two versions of the writers draw the very same solution;
``compare`` reads two ``write`` folders and prints, per session, whether the recordings hold the
same entity paths with the same values and the pages the same text and images (the provenance
table, which holds the run's clock, is left out).

Usage:
    python scripts/outputs_check.py solve SOLVED [--sessions DIR] [--only simgaps,euroc]
    python scripts/outputs_check.py write SOLVED OUT
    python scripts/outputs_check.py compare OUT_BEFORE OUT_AFTER
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import re
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"

#: name -> (command, simulate arguments per take (None: a real recording), extra options).
SESSIONS: dict[str, tuple[str, list[list[str]] | None, list[str]]] = {
    "simgaps": ("calibrate", [["--seed", "7", "--duration", "40", "-e", "time_offset=0.004",
                               "-e", "imu_dropouts=10", "-e", "imu_stalls=0.8"]], []),
    # Two takes of one rig (a seed the command line does not set): written by _simulate.
    "simtakes": ("calibrate", [["rig=77", "--seed", "21", "--duration", "40"],
                               ["rig=77", "--seed", "22", "--duration", "40"]], []),
    "simlong": ("calibrate", [["--seed", "31", "--duration", "330", "-e", "time_offset=0.003",
                               "-e", "mocap_dropouts=3"]], ["--segments", "0"]),
    "simdiag": ("diagnose", [["--seed", "41", "--duration", "40", "-e", "time_offset=0.004",
                              "-e", "accel_delay=0.004"]], []),
    "euroc": ("calibrate", None, []),
}


def _inputs(name: str, sim_dir: Path) -> list[str]:
    command, takes, _ = SESSIONS[name]
    if takes is None:
        return [str(DATA / "euroc_V2_03_difficult" / "mav0")]
    return [str(sim_dir / f"{name}_{k}" / "mav0") for k in range(len(takes))]


def _simulate(folder: Path, args: list[str]) -> None:
    """A simulated session written as a mav0 folder (``rig=N`` first: of rig seed N)."""
    from mocap_calib.cli.main import main

    if not args[0].startswith("rig="):
        assert main(["simulate", str(folder), *args]) == 0
        return
    from mocap_calib.io.formats.euroc import write_mav0
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    seed, duration = int(args[2]), float(args[4])
    sim = simulate_flight(SimConfig(seed=seed, duration=duration, rig_seed=int(args[0][4:]),
                                    effects={"time_offset": [0.002 * (seed % 5)]}))
    write_mav0(folder, sim.imu, sim.mocap)


def solve(solved: Path, sim_dir: Path, only: list[str]) -> None:
    """Simulate (once), run each session's command up to its solution, pickle it."""
    from mocap_calib.cli.main import main
    from mocap_calib.workflows import calibrate, diagnose

    solved.mkdir(parents=True, exist_ok=True)
    for name, (command, takes, extra) in SESSIONS.items():
        if only and name not in only:
            continue
        for k, args in enumerate(takes or []):
            folder = sim_dir / f"{name}_{k}"
            if not folder.exists():
                _simulate(folder, args)
        kept: dict[str, Any] = {}
        module = calibrate if command == "calibrate" else diagnose
        run_name = "run_calibration" if command == "calibrate" else "run_diagnosis"
        run = getattr(module, run_name)

        def keep(request, progress=None, run=run, kept=kept):
            kept["solution"] = run(request, progress)
            return kept["solution"]

        setattr(module, run_name, keep)
        try:
            assert main([command, *_inputs(name, sim_dir), *extra, "-q"]) == 0
        finally:
            setattr(module, run_name, run)
        with open(solved / f"{name}.pkl", "wb") as f:
            pickle.dump({"command": command, "args": [*_inputs(name, sim_dir), *extra],
                         "solution": kept["solution"]}, f)
        print(f"{name}: solved", flush=True)


def write(solved: Path, out: Path) -> None:
    """Each session's command with --rrd and --html, its solution taken from the pickle."""
    from mocap_calib.cli.main import main
    from mocap_calib.workflows import calibrate, diagnose

    out.mkdir(parents=True, exist_ok=True)
    for pkl in sorted(solved.glob("*.pkl")):
        with open(pkl, "rb") as f:
            saved = pickle.load(f)
        command = saved["command"]
        module = calibrate if command == "calibrate" else diagnose
        run_name = "run_calibration" if command == "calibrate" else "run_diagnosis"
        run = getattr(module, run_name)
        setattr(module, run_name, lambda request, progress=None, s=saved: s["solution"])
        name = pkl.stem
        t0 = time.perf_counter()
        try:
            code = main([command, *saved["args"], "--out", str(out / f"{name}.yaml"),
                         "--rrd", str(out / f"{name}.rrd"), "--html", str(out / f"{name}.html"),
                         "-q"])
        finally:
            setattr(module, run_name, run)
        assert code == 0, (name, code)
        print(f"{name}: written in {time.perf_counter() - t0:.2f} s", flush=True)


def _values(column: Any) -> str:
    """A column's values as a digest (floats exactly, by their bytes)."""
    return hashlib.sha256(repr(column.to_pylist()).encode()).hexdigest()[:16]


def rrd_digest(path: Path) -> dict[str, dict[str, list[str]]]:
    """Per entity path (recording properties left out), per column (row ids left out), the
    digests of its chunks' values, sorted."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list[str]]] = {}
    for chunk in RrdReader(path).stream():
        entity = chunk.entity_path
        if "__properties" in entity:
            continue
        b = chunk.to_record_batch()
        cols = out.setdefault(entity, {})
        for name in b.schema.names:
            if "RowId" in name or name.endswith("row_id"):
                continue
            cols.setdefault(name, []).append(_values(b.column(name)))
    for cols in out.values():
        for v in cols.values():
            v.sort()
    out["(blueprint)"] = {"views": _blueprint(path)}
    return out


def _blueprint(path: Path) -> list[str]:
    """The layout's views and containers with their names, origins and queries, sorted (the
    ids rerun draws at random and the log times left out)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    # An id as text, or as its 16 bytes.
    uuid = re.compile(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}"
                      r"|\[(\d+, ){15}\d+\]")
    rows = []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            b = chunk.to_record_batch()
            for name in b.schema.names:
                if name in ("rerun.controls.RowId", "blueprint", "log_time"):
                    continue
                rows.append(uuid.sub("<id>", f"{name}={b.column(name).to_pylist()}"))
    return sorted(rows)


def html_digest(path: Path) -> tuple[str, dict[str, str]]:
    """The page without its images and provenance table, and the images by their figure id."""
    text = path.read_text(encoding="utf-8")
    text = re.sub(r'<table id="provenance".*?</table>', "<provenance/>", text, flags=re.S)
    images: dict[str, str] = {}

    def image(m: re.Match[str]) -> str:
        images[str(len(images))] = hashlib.sha256(m.group(1).encode()).hexdigest()[:16]
        return f'src="image {len(images) - 1}"'

    text = re.sub(r'src="data:image/png;base64,([^"]*)"', image, text)
    return text, images


def compare(before: Path, after: Path) -> int:
    bad = 0
    for rrd in sorted(before.glob("*.rrd")):
        name = rrd.stem
        a, b = rrd_digest(rrd), rrd_digest(after / rrd.name)
        values = sum(len(v) for c in a.values() for v in c.values())
        diff = sorted(e for e in set(a) | set(b) if a.get(e) != b.get(e))
        ta, ia = html_digest(before / f"{name}.html")
        tb, ib = html_digest(after / f"{name}.html")
        texts = "same" if ta == tb else "DIFFERENT"
        imgs = sum(ia.get(k) != ib.get(k) for k in set(ia) | set(ib))
        print(f"{name}: rrd {len(a)} entity paths, {values} columns of chunks, "
              f"{len(diff)} differ{': ' + ', '.join(diff[:8]) if diff else ''}; "
              f"html text {texts} ({len(ta)} chars), {len(ia)} images, {imgs} differ")
        if ta != tb:
            la, lb = ta.splitlines(), tb.splitlines()
            first = next((i for i, (x, y) in enumerate(zip(la, lb, strict=False)) if x != y),
                         min(len(la), len(lb)))
            old = la[first][:300] if first < len(la) else ""
            new = lb[first][:300] if first < len(lb) else ""
            print(f"  first differing line {first}:\n  - {old}\n  + {new}")
        bad += bool(diff) + (ta != tb) + bool(imgs)
    print("identical" if bad == 0 else f"{bad} differences")
    return int(bad > 0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("solve")
    p.add_argument("solved", type=Path)
    p.add_argument("--sessions", type=Path, default=None)
    p.add_argument("--only", default="")
    p = sub.add_parser("write")
    p.add_argument("solved", type=Path)
    p.add_argument("out", type=Path)
    p = sub.add_parser("compare")
    p.add_argument("before", type=Path)
    p.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.cmd == "solve":
        solve(args.solved, args.sessions or args.solved / "sessions",
              [x for x in args.only.split(",") if x])
    elif args.cmd == "write":
        write(args.solved, args.out)
    else:
        sys.exit(compare(args.before, args.after))


if __name__ == "__main__":
    main()
