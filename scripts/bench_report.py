"""Benchmark: what ``calibrate --html`` adds to a run, and how large the report is.

A simulated session (200 Hz IMU, 100 Hz mocap, a few ms of clock offset, a few mocap gaps) is
written as a mav0 folder and calibrated through the workflow; then the HTML report is made
from the result, in the same process with matplotlib not yet imported (so its import counts).
Each session length runs in its own process. Prints the table of docs/validation.md
(``--write-doc`` rewrites its section there).

Usage: python scripts/bench_report.py [minutes ...] [--write-doc] [--doc PATH]   (default: 10)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _doc_section import add_doc_options, check, provenance, table, write

SECTIONS = ("bench_report",)


def run_one(minutes: float, seed: int = 3) -> dict:
    from mocap_calib.core.diagnosis.outputs import output_series
    from mocap_calib.workflows.calibrate import CalibrateRequest, InputSpec, run_calibration
    from mocap_calib.workflows.report_files import pages as html_report
    from mocap_calib.workflows.report_files.provenance import RunClock
    from mocap_calib.workflows.simulate import simulate_to_folder

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "session"
        simulate_to_folder(folder, seed=seed, duration=60.0 * minutes,
                           effects=["time_offset=0.004"])
        clock = RunClock()
        t0 = time.perf_counter()
        result, _ = run_calibration(CalibrateRequest(inputs=InputSpec(mav0=folder)))
        t_cal = time.perf_counter() - t0
        assert "matplotlib" not in sys.modules, "matplotlib was imported by the calibration"
        out = Path(tmp) / "report.html"
        t1 = time.perf_counter()
        series = output_series(result, report=True)
        t_extras = time.perf_counter() - t1  # residual analysis and dead reckoning
        html_report.write_calibration_html(out, result, series, [folder], clock)
        t_report = time.perf_counter() - t1  # what --html adds (matplotlib import included)
        size_mb = out.stat().st_size / 1e6
    return {
        "minutes": minutes, "calibration_s": round(t_cal, 2), "report_s": round(t_report, 2),
        "of_which_residual_analysis_and_dead_reckoning_s": round(t_extras, 2),
        "report_mb": round(size_mb, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("minutes", nargs="*", type=float, default=[10.0],
                        help="session lengths in minutes")
    parser.add_argument("--one", type=float, help=argparse.SUPPRESS)
    add_doc_options(parser)
    args = parser.parse_args()
    if args.one is not None:
        print(json.dumps(run_one(args.one)))
        return
    check(args, list(SECTIONS))
    rows = []
    for m in args.minutes:
        proc = subprocess.run([sys.executable, __file__, f"--one={m}"], capture_output=True,
                              text=True, check=True)
        line = proc.stdout.strip().splitlines()[-1]
        print(line, flush=True)
        r = json.loads(line)
        rows.append([f"{m:g} min", f"{r['calibration_s']:.1f} s", f"{r['report_s']:.1f} s",
                     f"{r['of_which_residual_analysis_and_dead_reckoning_s']:.1f} s",
                     f"{r['report_mb']:.2f} MB"])
    text = (provenance("bench_report.py") + "\n"
            + table(["simulated session", "calibration", "what `--html` adds",
                     "of which residual analysis and dead reckoning", "report size"], rows))
    print(text)
    write(args, {"bench_report": text})


if __name__ == "__main__":
    main()
