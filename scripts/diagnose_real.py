"""The diagnosis on every real recording in ../shared/data: the gap (low-band residual over the
noise floor) step by step, what was found, what was implausible, and the unexplained signature.

Usage: python scripts/diagnose_real.py [--only euroc,broad21] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from real_data_study import RECORDINGS  # noqa: E402

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose  # noqa: E402
from mocap_calib.workflows.session import NoiseSpec, load_session  # noqa: E402


def run(key: str) -> dict:
    label, spec = RECORDINGS[key]
    session = load_session(spec)
    opts = DiagnoseOptions()
    opts.calibration.noise = NoiseSpec().resolve(session.sensor_noise)
    rep = diagnose(session.imu, session.mocap, opts)
    # The last step is the final calibration with the model found (clock search and noise
    # model chosen from the session, as `calibrate` does).
    steps = [{"model": s.model, "gyro_gap": round(s.residuals.ratio("gyro"), 2),
              "accel_gap": round(s.residuals.ratio("accel"), 2), "added": s.added,
              "final_calibration": k == len(rep.steps) - 1}
             for k, s in enumerate(rep.steps)]
    return {"recording": label, "found": rep.found,
            "implausible": [{k: x[k] for k in ("effect", "reason")} for x in rep.implausible],
            "steps": steps, "unexplained": rep.unexplained, "seconds": round(rep.seconds, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(RECORDINGS))
    ap.add_argument("--json")
    a = ap.parse_args()
    out = []
    for key in a.only.split(","):
        r = run(key)
        print(json.dumps(r, indent=1), flush=True)
        out.append(r)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
