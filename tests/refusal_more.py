"""The corpus cases of issue 23: column maps that were dropped, files a column short or in
another delimiter, swapped IMU columns, one-axis motion that fit upside down, marker swaps
(isolated: removed, the session calibrates; in runs: their holes leave too few intervals),
``--start`` beyond the session. Built from the helpers of :mod:`refusal_corpus`; :data:`ALL_CASES`
is its ``CASES`` and these."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from refusal_corpus import CASES, Case, Expect, _calibrate, _imu, _mocap, clean, mav0, session

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import MocapPoses
from mocap_calib.io.formats.euroc import write_mav0
from mocap_calib.io.formats.tum import write_tum


def _poses_file(sep: str, header: bool = True, drop: int | None = None
                ) -> Callable[[Path], list[str]]:
    """The clean session's EuRoC pose file rewritten with another delimiter, without its
    header, or without one column; given with --imu/--mocap."""
    def build(d: Path) -> list[str]:
        root = write_mav0(d, clean().imu, clean().mocap)
        rows = [[t.strip() for t in line.split(",")]
                for line in (root / "vicon0" / "data.csv").read_text().splitlines()]
        if drop is not None:
            rows = [r[:drop] + r[drop + 1:] for r in rows]
        out = d / "poses.txt"
        out.write_text("\n".join(sep.join(r) for r in rows[0 if header else 1:]) + "\n")
        return ["--imu", str(root / "imu0" / "data.csv"), "--mocap", str(out)]
    return build


def _tum_seven_columns(d: Path) -> list[str]:
    root = write_mav0(d, clean().imu, clean().mocap)
    tum = write_tum(d / "poses.txt", clean().mocap)
    tum.write_text("\n".join(" ".join(line.split()[:7]) if not line.startswith("#") else line
                             for line in tum.read_text().splitlines()) + "\n")
    return ["--imu", str(root / "imu0" / "data.csv"), "--mocap", str(tum)]


def marker_swaps(fraction: float = 0.05, seed: int = 1, run: int = 1) -> MocapPoses:
    """Samples where the rigid body was solved with its markers swapped: the pose turned
    120 deg about a body axis and shifted 3 cm; isolated, or in runs of ``run`` frames."""
    m = clean().mocap
    starts = np.random.default_rng(seed).choice(np.arange(2, len(m.t) - 2 - run),
                                                size=int(fraction * len(m.t) / run),
                                                replace=False)
    k = np.unique((starts[:, None] + np.arange(run)[None, :]).ravel())
    q, p = m.quat_wxyz.copy(), m.position.copy()
    q[k] = so3.rotmat_to_quat(so3.quat_to_rotmat(q[k]) @ so3.exp(np.radians([0.0, 0.0, 120.0])))
    p[k] += [0.03, 0.0, 0.0]
    return _mocap(clean(), q, p)


def _one_axis(motion: str) -> Callable[[Path], list[str]]:
    # Seed 4, 30 s: a session whose fit turns gravity upside down (2 g of accel bias).
    def build(d: Path) -> list[str]:
        s = session(seed=4, motion=motion, duration=30.0)
        return mav0(s.imu, s.mocap)(d)
    return build


MORE_CASES: list[Case] = [
    Case("columns_five_for_three", "option files",
         "--columns accel=4:9 on EuRoC files (five columns for a 3-vector)",
         _calibrate(mav0(None, None, "--columns", "accel=4:9")),
         Expect(2, ("--columns", "accel= names 5 columns", "3"))),
    Case("columns_on_euroc_used", "option files",
         "--columns that swaps gyro and accel, on EuRoC files",
         _calibrate(mav0(None, None, "--columns", "t=0,gyro=4:7,accel=1:4")),
         Expect(2, ("swapped",))),
    Case("mocap_tab_separated", "file layout", "EuRoC pose file with tabs for commas",
         _calibrate(_poses_file("\t")), Expect(0)),
    Case("mocap_semicolon_separated", "file layout", "EuRoC pose file with semicolons",
         _calibrate(_poses_file(";")), Expect(0)),
    Case("mocap_tab_no_header", "file layout",
         "EuRoC pose rows, tab-separated, without the header",
         _calibrate(_poses_file("\t", header=False)),
         Expect(2, ("nanosecond", "without a header", "EuRoC", "--columns"))),
    Case("mocap_missing_qz", "file layout", "EuRoC pose file without its q_z column",
         _calibrate(_poses_file(",", drop=7)),
         Expect(2, ("EuRoC mocap rows have 8 columns", "this one has 7", "q_RS_z"))),
    Case("mocap_missing_column_no_header", "file layout",
         "EuRoC pose rows without header and one column",
         _calibrate(_poses_file(",", header=False, drop=2)),
         Expect(2, ("EuRoC mocap rows have 8 columns", "this one has 7"))),
    Case("tum_seven_columns", "file layout", "TUM trajectory of 7 columns",
         _calibrate(_tum_seven_columns),
         Expect(2, ("TUM rows have 8 columns", "this one has 7"))),
    Case("gyro_accel_swapped", "conventions", "gyro and accel columns swapped",
         _calibrate(lambda d: mav0(_imu(clean(), gyro=clean().imu.accel,
                                        accel=clean().imu.gyro))(d)),
         Expect(2, ("swapped", "swap them"))),
    Case("turntable_upside_down", "degenerate",
         "turntable whose fit turns gravity upside down",
         _calibrate(_one_axis("turntable")),
         Expect(3, ("one axis only", "turntable", "accelerometer bias", "gravity",
                    "lever arm", "tilts the body"))),
    Case("planar_upside_down", "degenerate",
         "ground robot whose fit turns gravity upside down",
         _calibrate(_one_axis("planar")),
         Expect(3, ("one axis only", "ground robot", "accelerometer bias", "gravity"))),
    Case("marker_swaps", "faults", "5 % isolated marker swaps",
         _calibrate(lambda d: mav0(None, marker_swaps())(d)),
         Expect(0, notes=("marker swaps", "were removed"))),
    Case("marker_swap_runs", "faults", "15 % of the frames marker-swapped in runs of 3",
         _calibrate(lambda d: mav0(None, marker_swaps(0.15, run=3))(d)),
         Expect(3, ("marker swaps", "were removed", "mocap samples", "holes"))),
    Case("start_beyond_session", "option values", "--start 100 on a 30 s session",
         _calibrate(mav0(None, None, "--start", "100")),
         Expect(2, ("--start 100", "spans 0 to 30.0 s"))),
]

#: The whole corpus (tests/test_refusals.py, scripts/refusal_table.py).
ALL_CASES: list[Case] = [*CASES, *MORE_CASES]
