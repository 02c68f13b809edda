"""Run the refusal corpus (tests/refusal_corpus.py) and write docs/refusals.md: every case, the
command, the verdict (exit code and the line the user sees, or what the result reports), and
whether the verdict is right.

    .venv/bin/python scripts/refusal_table.py            # writes docs/refusals.md
    .venv/bin/python scripts/refusal_table.py --print    # only prints the table
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from refusal_corpus import run_case  # noqa: E402
from refusal_more import ALL_CASES as CASES  # noqa: E402

#: What the same inputs gave at commit 151d384, before the refusals, run the same way; for the
#: cases of refusal_more.py, at commit d8dff8f, before their checks.
BEFORE = {
    "clean": "exit 0, right",
    "clean_offset": "exit 0, right",
    "accel_sign": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "imu_y_flipped": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "inverse_pose": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "jpl_quaternions": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "xyzw_quaternions": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "position_cm": "exit 2, 'the positions look like millimetres; pass --position-unit mm' "
                   "(wrong unit)",
    "position_cm_as_mm": "exit 3, 'cannot resolve the clock offset ...'",
    "position_mm_as_cm": "exit 2, \"unknown --position-unit 'cm'\"",
    "gyro_deg_slow": "exit 2, names deg/s",
    "two_recordings": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "disjoint_halves": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'",
    "turntable": "exit 3, 'cannot resolve the clock offset ... (periodic motion?)'; with the "
                 "clock resolved: exit 0, R_MI 26 deg and p_MI 470 mm off (sigma 1 deg, 10 mm)",
    "planar": "exit 3, 'cannot resolve the clock offset'; with the clock resolved: exit 0, "
              "p_MI 295 mm off along the yaw axis (sigma 7 mm)",
    "slow": "exit 4, 'implausible: the fit moved the clock offset 166 ms'",
    "saturated": "exit 0, no note of the clipping",
    "accel_dead": "exit 3, 'cannot resolve the clock offset ...'",
    "gyro_z_dead": "exit 4 after 45 s, 'implausible calibration: gyro bias 0.58 rad/s ...'",
    "mocap_frozen": "exit 0, R_MI 2.9 deg off",
    "imu_frozen": "exit 4, 'implausible calibration: accel bias of 1.72 m/s^2 ...'",
    "mocap_dead": "exit 3, 'the session is (nearly) static'",
    "noise_binary": "exit 70, internal error: UnicodeDecodeError",
    "noise_empty": "exit 2, 'expected a YAML mapping'",
    "noise_list": "exit 2, 'expected a YAML mapping'",
    "prior_binary": "exit 70, internal error: UnicodeDecodeError",
    "prior_malformed": "exit 2, \"missing key 'accel_bias'\"",
    "calibration_binary": "exit 70, internal error: UnicodeDecodeError",
    "columns_twice": "exit 2, 'the accelerometer looks like it is in g' (wrong cause)",
    "columns_reversed": "exit 2, 'empty column'",
    "imu_stamps_s": "exit 2, 'IMU timestamp repeats the previous row's'",
    "mocap_stamps_us": "exit 3, 'the session is only 0.0 s long'",
    "stamps_5000_digits": "exit 2, 'timestamps overflow 64-bit nanoseconds'",
    "stamps_ms_as_s": "exit 2, names ms",
    "stamps_ns_as_s": "exit 2, 'timestamps overflow 64-bit nanoseconds' (no unit named)",
    "diagnose_two_recordings": "exit 4, 'the attitude stage did not converge'",
    "diagnose_gyro_deg_slow": "exit 2, names deg/s",
    "diagnose_accel_dead": "exit 4 after 47 s, 'the position stage did not converge'",
    "allan_dead_accel": "exit 3, 'accelerometer x axis is constant'",
    "allan_frozen": "exit 3, 'gyroscope random walk not resolved' (frozen span not named)",
    "multipos_dead_gyro": "exit 70, internal error: ValueError",
    # refusal_more.py's cases at commit d8dff8f, run the same way.
    "columns_five_for_three": "d8dff8f: exit 0, the map dropped with a note",
    "columns_on_euroc_used": "d8dff8f: exit 0, the map dropped with a note",
    "mocap_tab_separated": "d8dff8f: exit 2, 'timestamps overflow ... they look like ns: pass "
                           "--time-unit ns' (read as TUM; that fix then fails on the "
                           "quaternion order)",
    "mocap_semicolon_separated": "d8dff8f: exit 0, right",
    "mocap_tab_no_header": "d8dff8f: exit 2, 'timestamps overflow ... pass --time-unit ns'",
    "mocap_missing_qz": "d8dff8f: exit 2, 'format not recognised (not EuRoC or TUM)'",
    "mocap_missing_column_no_header": "d8dff8f: exit 2, 'format not recognised'",
    "tum_seven_columns": "d8dff8f: exit 2, 'format not recognised'",
    "gyro_accel_swapped": "d8dff8f: exit 2, 'the accelerometer looks like it is in g; pass "
                          "--accel-unit g' (wrong cause)",
    "turntable_upside_down": "d8dff8f: exit 4, 'implausible calibration: accel bias of 18.9 "
                             "m/s^2'",
    "planar_upside_down": "d8dff8f: exit 4, 'implausible calibration: accel bias of 19.6 m/s^2'",
    "marker_swaps": "d8dff8f: exit 3, 'only 5 gap-free keyframe intervals ...; the session is "
                    "too short or the mocap has too many gaps'",
    "start_beyond_session": "d8dff8f: exit 2, 'only 0 IMU samples; a calibration needs at "
                            "least a few thousand'",
    # The cases of files, processes and numbers, before their checks (commit 1da82c7).
    "out_is_imu": "1da82c7: exit 0, the IMU log replaced by the result",
    "out_is_html": "1da82c7: exit 0, the HTML page written over the result, 'wrote r.yaml' "
                   "printed twice",
    "export_onto_itself": "1da82c7: exit 0, the calibration replaced by the Kalibr file",
    "groundtruth_sidecar_onto_calibration": "1da82c7: exit 0, the calibration replaced by the "
                                            "sidecar",
    "prior_translation_1e308": "1da82c7: exit 0, a result written",
    "prior_negative_sigma": "1da82c7: exit 70, internal error: ValueError (GTSAM: sigma values "
                            "must be non-negative)",
    "prior_conflicting": "cff7924: exit 0, p_MI 48.6 mm off the truth (sigma 0.27 mm), "
                         "nothing said of the prior",
    "prior_consistent": "cff7924: exit 0, right, nothing said of the prior",
    "noise_1e30": "1da82c7: exit 3, 'the data do not determine every parameter (GTSAM: "
                  "indeterminate linear system)' (wrong cause)",
    "plausible_nan": "1da82c7: exit 0, the accel bias check off",
    "manifest_4301_digits": "1da82c7: exit 70, internal error: ValueError (integer string "
                            "conversion)",
    "manifest_impossible_date": "1da82c7: exit 70, internal error: ValueError: day is out of "
                                "range for month",
    "manifest_alias_bomb": "1da82c7: not rerun; hundreds of MB of error text, then MemoryError",
    "batch_id_batch_yaml": "1da82c7: exit 70 after the first session, internal error: "
                           "NotADirectoryError",
    "scheduler_without_port": "1da82c7: exit 70, internal error: ValueError: missing port "
                              "number",
    "groundtruth_rate_100k": "1da82c7: not rerun; no bound, memory grows with the rate "
                             "(gigabytes)",
    "export_nan_quaternion": "1da82c7: exit 0, '\"px\": NaN' in the JSON (invalid JSON)",
    "export_zero_quaternion": "1da82c7: exit 0, 'EKF2_EV_POS_X nan'",
    "html_name_not_utf8": "1da82c7: exit 70, internal error: UnicodeEncodeError (surrogates "
                          "not allowed)",
}


def _cell(text: str, width: int = 440) -> str:
    text = text.replace("|", "\\|").replace("\n", " ")
    return text if len(text) <= width else text[: width - 3] + "..."


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--print", action="store_true", help="print the table, write nothing")
    args = ap.parse_args()
    rows = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            v = run_case(case, Path(tmp) / case.name)
            verdict = "right" if v.ok else "WRONG: " + "; ".join(v.problems)
            shown = v.line.removeprefix("error: ").replace(tmp + "/", "")
            rows.append(f"| {case.kind} | {case.what} | `{v.command}` | exit {v.code}: "
                        f"{_cell(shown)} | {verdict} | {_cell(BEFORE.get(case.name, '-'))} |")
            print(f"{case.name}: exit {v.code} {verdict}", file=sys.stderr)
    seconds = time.perf_counter() - t0
    table = "\n".join(["| kind | what the user did | command | what happens now | verdict | "
                       "before |", "|---|---|---|---|---|---|", *rows])
    if args.print:
        print(table)
        return
    head = (ROOT / "docs" / "refusals.md").read_text().split("<!-- table -->")[0]
    (ROOT / "docs" / "refusals.md").write_text(
        f"{head}<!-- table -->\n\n{table}\n\n{len(rows)} cases, {seconds:.0f} s on this "
        "machine (scripts/refusal_table.py).\n")


if __name__ == "__main__":
    main()
