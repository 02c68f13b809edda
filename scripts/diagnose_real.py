"""The diagnosis on every real recording in ../shared/data: the gap (low-band residual over the
noise floor) step by step, what was found, what was implausible, and the unexplained signature.
Prints the table of docs/validation.md (``--write-doc`` rewrites its section there, from a run
over every recording).

Usage: python scripts/diagnose_real.py [--only euroc,broad21] [--json out.json] [--write-doc]
       [--doc PATH]
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _doc_section import add_doc_options, check, provenance, table, write  # noqa: E402
from real_data_study import RECORDINGS  # noqa: E402

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose  # noqa: E402
from mocap_calib.errors import CalibrationError, Interrupted  # noqa: E402
from mocap_calib.workflows.session import NoiseSpec, load_session  # noqa: E402

SECTIONS = ("diagnose_real",)
ORDINAL = {1: "1st", 2: "2nd", 3: "3rd"}


def run(key: str) -> dict:
    label, spec = RECORDINGS[key]
    session = load_session(spec)
    opts = DiagnoseOptions()
    opts.calibration.noise = NoiseSpec().resolve(session.sensor_noise)
    t0 = time.perf_counter()
    try:
        rep = diagnose(session.imu, session.mocap, opts)
    except Interrupted:
        raise
    except CalibrationError as err:  # a refusal is a result of the study, with its cause
        return {"recording": label, "refused": f"exit {err.exit_code}: {err}",
                "seconds": round(time.perf_counter() - t0, 1)}
    # The last step is the final calibration with the model found (clock search and noise
    # model chosen from the session, as `calibrate` does).
    steps = [{"model": s.model, "gyro_gap": round(s.residuals.ratio("gyro"), 2),
              "accel_gap": round(s.residuals.ratio("accel"), 2), "added": s.added,
              "final_calibration": k == len(rep.steps) - 1}
             for k, s in enumerate(rep.steps)]
    return {"recording": label, "start": rep.start_model, "found": rep.found,
            "implausible": [{k: x[k] for k in ("effect", "reason")} for x in rep.implausible],
            "steps": steps, "unexplained": rep.unexplained, "seconds": round(rep.seconds, 1)}


def markdown(reports: list[dict]) -> str:
    """The section of docs/validation.md: one column per recording, one row per step (a
    refused recording: its exit code and cause, to the first clause, in the first row)."""
    done = [r for r in reports if "steps" in r]
    n_added = max((len(r["steps"]) - 2 for r in done), default=0)  # base, final: no effect

    def gap(st: dict) -> str:
        return f"{st['gyro_gap']:.3g} / {st['accel_gap']:.3g}"

    def refused(r: dict) -> str:
        code, _, cause = r["refused"].partition(": ")
        return f"{code}: {re.split(r' [(]|: ', cause, maxsplit=1)[0]}"

    starts = sorted({r["start"] for r in done}) or ["the starting model"]
    rows = [[f"start: {' / '.join(starts)}", *(gap(r["steps"][0]) if "steps" in r
                                                else f"refused, {refused(r)}"
                                                for r in reports)]]
    clock_first = all(r["steps"][0]["added"] == "time_offset" for r in done)
    for k in range(1, n_added + 1):
        named = not (k == 1 and clock_first)
        name = "+ time_offset" if not named else f"+ {ORDINAL.get(k, f'{k}th')} effect"
        cells = []
        for r in reports:
            st = r["steps"][k] if "steps" in r and k < len(r["steps"]) - 1 else None
            added = r["steps"][k - 1]["added"] if st else None
            cells.append("-" if st is None else (f"{added}: {gap(st)}" if named else gap(st)))
        rows.append([name, *cells])
    def final(r: dict) -> str:
        # The last effect found enters only the final calibration: named there.
        last = r["steps"][-2]["added"] if len(r["steps"]) > 1 else None
        return f"+ {last}: {gap(r['steps'][-1])}" if last else gap(r["steps"][-1])

    rows.append(["final calibration", *(final(r) if "steps" in r else "-" for r in reports)])
    rows.append(["significant but implausible (not in `found`)",
                 *("; ".join(f"{x['effect']} ({x['reason']})" for x in r.get("implausible", []))
                   or "-" for r in reports)])
    rows.append(["run time", *(f"{r['seconds']:.0f} s" for r in reports)])
    return (provenance("diagnose_real.py") + "\n"
            + table(["step", *(r["recording"] for r in reports)], rows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(RECORDINGS))
    ap.add_argument("--json")
    add_doc_options(ap)
    a = ap.parse_args()
    keys = a.only.split(",")
    full = set(RECORDINGS) <= set(keys)
    if full:
        check(a, list(SECTIONS))
    out = []
    for key in keys:
        r = run(key)
        print(json.dumps(r, indent=1), flush=True)
        out.append(r)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))
    text = markdown(out)
    print(text)
    write(a, {"diagnose_real": text} if full else {})


if __name__ == "__main__":
    main()
