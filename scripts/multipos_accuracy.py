"""Accuracy of ``multipos`` on simulated sessions: SI readings, raw 16-bit counts (no units
given), and a hidden gyro g-sensitivity. Prints the worst errors against the simulator's truth
over the seeds, and the gyro-integration residual with and without G, as the markdown of
docs/validation.md (``--write-doc`` rewrites its section there).

    python scripts/multipos_accuracy.py --seeds 5 [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _doc_section import add_doc_options, check, provenance, table, write

from mocap_calib.core.intrinsics.multipos import calibrate_multipos
from mocap_calib.core.intrinsics.multipos.units import RawConversion
from mocap_calib.sim.multipos import G_STD, CountsSpec, simulate_multipos

SECTIONS = ("multipos_accuracy",)

#: The accuracy multipos is specified for (display units of ``errors``).
SPECIFIED = {"accel scale (%)": "0.1 %", "accel misalignment (deg)": "0.05 deg",
             "accel bias": "5e-3 m/s^2", "gyro scale (%)": "0.1 %",
             "gyro misalignment (deg)": "0.05 deg", "gyro bias": "1e-4 rad/s"}


def errors(res, truth) -> dict[str, float]:
    out = {}
    off = ~np.eye(3, dtype=bool)
    for s in ("accel", "gyro"):
        M, T = getattr(res, f"{s}_matrix"), np.asarray(truth[f"{s}_matrix"])
        out[f"{s} scale (%)"] = 100 * float(np.max(np.abs(np.diag(M) / np.diag(T) - 1)))
        out[f"{s} misalignment (deg)"] = float(np.degrees(np.max(np.abs(
            (M - T) / np.diag(T)[:, None])[off])))
        out[f"{s} bias"] = float(np.max(np.abs(getattr(res, f"{s}_bias")
                                               - np.asarray(truth[f"{s}_bias"]))))
    return out


def _sci(x: float) -> str:
    return f"{x:.1e}".replace("e-0", "e-").replace("e+0", "e+")


def _cell(key: str, x: float) -> str:
    if key.endswith("(%)"):
        return f"{x:.2g} %"
    if key.endswith("(deg)"):
        return f"{x:.2g} deg"
    return _sci(x)


def markdown(n: int, rows: dict[str, list[dict[str, float]]], g_stats: np.ndarray,
             g_left_out: int, seconds: list[float]) -> str:
    """The section of docs/validation.md: worst errors, then G's recovery and the timing."""
    names = {"SI readings": "SI readings", "raw counts": "raw counts",
             "raw counts + G": "raw counts + hidden G"}
    body = [[k.replace(" (%)", "").replace(" (deg)", ""), SPECIFIED[k],
             *(_cell(k, max(e[k] for e in v)) for v in rows.values())] for k in SPECIFIED]
    g = g_stats
    return (provenance("multipos_accuracy.py") + "\n"
            + table([f"worst error over {n} seeds", "specified",
                     *(names[k] for k in rows)], body) + "\n"
            f"With the hidden `G`: `G` recovered within {100 * np.nanmax(g[:, 0]):.2g} % of its "
            f"norm; the gyro residual (gravity direction after each rotation) is "
            f"{g[:, 1].min():.3f}-{g[:, 1].max():.3f} deg with `G` in the model and "
            f"{g[:, 2].min():.2f}-{g[:, 2].max():.2f} deg without it. Without a hidden `G` the "
            f"test leaves it out of the model in {g_left_out} of {n} sessions (raw counts). "
            f"One calibration takes {min(seconds):.1f}-{max(seconds):.1f} s.\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    add_doc_options(ap)
    args = ap.parse_args()
    check(args, list(SECTIONS))
    n = args.seeds
    c = CountsSpec()
    conv = RawConversion(c.accel_scale, c.accel_offset, c.gyro_scale, c.gyro_offset)
    rows: dict[str, list[dict[str, float]]] = {"SI readings": [], "raw counts": [],
                                               "raw counts + G": []}
    g_stats = []
    seconds: list[float] = []
    g_left_out = 0

    def timed(imu, **kw):
        t0 = time.perf_counter()
        res = calibrate_multipos(imu, **kw)
        seconds.append(time.perf_counter() - t0)
        return res

    for seed in range(n):
        imu, truth = simulate_multipos(seed)
        rows["SI readings"].append(errors(timed(imu), truth))
        imu, truth = simulate_multipos(seed, counts=c)
        res = timed(imu, raw=True)
        g_left_out += res.g_sensitivity is None
        rows["raw counts"].append(errors(res.in_units(conv), truth))
        imu, truth = simulate_multipos(seed, counts=c, g_sensitivity=G_STD)
        res = timed(imu, raw=True).in_units(conv)
        rows["raw counts + G"].append(errors(res, truth))
        G = np.asarray(truth["g_sensitivity"])
        t = res.g_sensitivity_test
        g_stats.append((float(np.linalg.norm(res.g_sensitivity - G) / np.linalg.norm(G))
                        if res.g_sensitivity is not None else np.nan,
                        np.degrees(t["gyro_rms_rad_with_g"]),
                        np.degrees(t["gyro_rms_rad_without_g"])))
    text = markdown(n, rows, np.array(g_stats), g_left_out, seconds)
    print(text)
    write(args, {"multipos_accuracy": text})


if __name__ == "__main__":
    main()
