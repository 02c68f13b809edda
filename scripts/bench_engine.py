"""Benchmark: the cost of one position-stage window evaluation, apart from how many there are.

``capture`` calibrates a session once and keeps what the position stage worked with (prepared
session, windows, robust weights, noise model, solution) in a pickle; ``time`` rebuilds the
window engine from it and times its evaluations: a full (unfrozen) evaluation, the recording of
a frozen whitening, a frozen replay, and the noise-model choice (likelihood-only passes on a
subset of the windows; its cost per 1000 steps is per step of the whole problem). The same
pickle serves the code before and after a change, so the figures compare like with like.

Figures: best of ``--repeat`` runs, wall and CPU (all threads) ms per evaluation and per 1000
window-steps (windows x padded steps), on 1 and 2 chunk threads. CPU time is the steadier
figure when other processes load the machine.

``time`` prints the problem's row of the table of docs/validation.md (CPU ms per 1000
window-steps on one thread); ``--write-doc`` puts it into that section (replacing the row with
the same ``--label``, or adding it).

Usage:
    python scripts/bench_engine.py capture SRC OUT.pkl     SRC: sim:MINUTES, a mav0 folder or
                                                           IMU.csv,MOCAP.csv (EuRoC layout)
    python scripts/bench_engine.py time OUT.pkl [--repeat 5] [--label TEXT] [--write-doc]
                                   [--doc PATH]
"""

from __future__ import annotations

import argparse
import pickle
import resource
import time
from pathlib import Path

from _doc_section import add_doc_options, check, read_section, table, upsert_row, write

SECTIONS = ("bench_engine",)
HEADER = ["problem", "full evaluation", "frozen replay", "noise-model choice"]


def capture(src: str, out: Path) -> None:
    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate

    if src.startswith("sim:"):
        from mocap_calib.sim.flight import SimConfig, simulate_flight

        sim = simulate_flight(SimConfig(seed=1, duration=60.0 * float(src[4:]),
                                        effects={"time_offset": [0.004]}))
        res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    else:
        from mocap_calib.workflows.calibrate import CalibrateRequest, run_calibration
        from mocap_calib.workflows.session import InputSpec

        parts = src.split(",")
        spec = (InputSpec(imu=(Path(parts[0]),), mocap=(Path(parts[1]),)) if len(parts) == 2
                else InputSpec(mav0=(Path(src),)))
        res, _ = run_calibration(CalibrateRequest(inputs=spec))
    tr = res.diagnostics.trace
    pos = tr.position
    keep = {"session": tr.session, "model": tr.model_state.model, "noise": pos.noise,
            "windows": pos.windows, "weights": pos.weights, "t_mid": tr.model_state.t_mid,
            "R_MI": pos.R_MI, "p_MI": pos.p_MI, "g_dir": pos.g_dir, "g_mag": pos.g_mag,
            "delta": pos.delta, "effects": pos.effects, "knots": pos.knots}
    out.write_bytes(pickle.dumps(keep))
    w = pos.windows
    print(f"captured {src}: {w.count} windows x {w.steps} steps -> {out}")


def _timed(fn, repeat: int) -> tuple[float, float]:
    """Best wall and best CPU (process) time of ``repeat`` calls."""
    wall = cpu = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def time_engine(path: Path, repeat: int) -> list[float]:
    """Prints the figures; returns CPU ms per 1000 window-steps on one thread: full
    evaluation, frozen replay, noise-model choice."""
    import gtsam

    from mocap_calib.core.position.engine import PositionProblem, Theta
    from mocap_calib.core.threads import set_chunk_threads
    from mocap_calib.core.uncertainty.mocap_noise import fit_mocap_correlation

    d = pickle.loads(path.read_bytes())
    win = d["windows"]
    th = Theta(d["R_MI"], d["p_MI"], d["g_dir"], gtsam.Unit3(d["g_dir"]).basis(), d["g_mag"],
               d["delta"], d["effects"], d["knots"], d["t_mid"])
    steps = win.count * win.steps
    print(f"{path.name}: {win.count} windows x {win.steps} steps = {steps} window-steps, "
          f"model {d['model']}, correlated mocap noise: {d['noise'].mocap_correlated}")
    t_first = time.perf_counter()
    pp = PositionProblem(d["session"], d["model"], d["noise"], win)
    pp.weights = d["weights"].copy()
    pp.collect_scores = True
    pp.evaluate(th)
    print(f"  first evaluation (compiles or loads kernels): {time.perf_counter() - t_first:.2f} s")
    one_thread: list[float] = []
    for threads in (1, 2):
        set_chunk_threads(threads)
        full = _timed(lambda: pp.evaluate(th), repeat)

        def record() -> None:
            pp.freeze_whitening(True)
            pp.evaluate(th)
        rec = _timed(record, repeat)
        frozen = _timed(lambda: pp.evaluate(th), repeat)
        pp.freeze_whitening(False)
        lik = _timed(lambda: fit_mocap_correlation(pp, th), repeat)
        print(f"  {threads} thread(s), wall / CPU ms per evaluation (per 1000 steps): " + ", ".join(
            f"{name} {1e3 * w:.0f} / {1e3 * c:.0f} ({1e6 * w / steps:.1f} / {1e6 * c / steps:.1f})"
            for name, (w, c) in (("full", full), ("record", rec), ("frozen", frozen),
                                 ("noise-model choice", lik))), flush=True)
        if threads == 1:
            one_thread = [1e6 * c / steps for _, c in (full, frozen, lik)]
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"  peak RSS {rss:.0f} MB")
    return one_thread


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("capture")
    c.add_argument("src")
    c.add_argument("out", type=Path)
    t = sub.add_parser("time")
    t.add_argument("pickle", type=Path)
    t.add_argument("--repeat", type=int, default=3)
    t.add_argument("--label", help="the row's first cell (default: the pickle's name)")
    add_doc_options(t)
    args = ap.parse_args()
    if args.cmd == "capture":
        capture(args.src, args.out)
        return
    check(args, list(SECTIONS))
    cells = [args.label or args.pickle.name,
             *(f"{x:.1f}" for x in time_engine(args.pickle, args.repeat))]
    print(table(HEADER, [cells]))
    if args.write_doc:
        write(args, {"bench_engine": upsert_row(read_section(args.doc, "bench_engine"), cells)})


if __name__ == "__main__":
    main()
