"""Every bad input gives one InputError line naming the file, the line (where one is to blame)
and the fix; occlusions (NaN mocap rows) are dropped without an error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import refused as raises

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.io.formats.columns import parse_columns
from mocap_calib.io.formats.euroc import (
    read_euroc_imu,
    read_euroc_poses,
    read_mav0,
    write_euroc_imu,
    write_euroc_poses,
    write_mav0,
)
from mocap_calib.io.formats.generic import read_generic
from mocap_calib.io.formats.tum import read_tum, write_tum
from mocap_calib.io.loader import load_inputs

T0_NS = 1_000_000_000_000


def make_imu(n: int = 300, seed: int = 0) -> ImuSamples:
    rng = np.random.default_rng(seed)
    ns = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    gyro = 0.2 * rng.normal(size=(n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + 0.3 * rng.normal(size=(n, 3))
    return ImuSamples((ns - T0_NS) / 1e9, gyro, accel, T0_NS)


def make_mocap(n: int = 100, seed: int = 1) -> MocapPoses:
    rng = np.random.default_rng(seed)
    ns = T0_NS + np.arange(n, dtype=np.int64) * 10_000_000
    q = so3.rotmat_to_quat(so3.exp(0.5 * rng.normal(size=(n, 3))))
    return MocapPoses((ns - T0_NS) / 1e9, q, rng.uniform(-2, 2, size=(n, 3)), T0_NS)


def imu_lines(tmp_path: Path, **kw: int) -> list[str]:
    """Lines of a valid EuRoC imu0 file (line k of the file is ``lines[k - 1]``)."""
    return write_euroc_imu(tmp_path / "ok_imu.csv", make_imu(**kw)).read_text().splitlines()


def pose_lines(tmp_path: Path, **kw: int) -> list[str]:
    return write_euroc_poses(tmp_path / "ok_pose.csv", make_mocap(**kw)).read_text().splitlines()


def put(tmp_path: Path, name: str, lines: list[str]) -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def set_field(lines: list[str], line: int, field: int, value: str, sep: str = ",") -> None:
    parts = lines[line - 1].split(sep)
    parts[field] = value
    lines[line - 1] = sep.join(parts)



# --- structure -------------------------------------------------------------------------------

def test_empty_and_header_only(tmp_path: Path) -> None:
    empty = put(tmp_path, "empty.csv", [""])
    raises(lambda: read_euroc_imu(empty), str(empty), "empty", "pass the file")
    header = put(tmp_path, "header.csv", imu_lines(tmp_path)[:1])
    raises(lambda: read_euroc_imu(header), str(header), "no data rows", "pass the file")
    missing = tmp_path / "nope.csv"
    raises(lambda: read_euroc_imu(missing), str(missing), "not found", "check the path")


def test_missing_and_wrong_columns(tmp_path: Path) -> None:
    lines = imu_lines(tmp_path)
    short = put(tmp_path, "short.csv", [",".join(ln.split(",")[:6]) for ln in lines])
    raises(lambda: read_euroc_imu(short), str(short), "line 1", "a_RS_S_z [m s^-2]", "missing",
           "--columns")
    renamed = [lines[0].replace("a_RS_S_x", "acc_x")] + lines[1:]
    path = put(tmp_path, "renamed.csv", renamed)
    raises(lambda: read_euroc_imu(path), str(path), "line 1", "column 5 is 'acc_x [m s^-2]'",
           "expects 'a_RS_S_x [m s^-2]'", "header")
    nohead = put(tmp_path, "nohead.csv", lines[1:])
    raises(lambda: read_euroc_imu(nohead), str(nohead), "no header line", "--columns")
    # Data rows shorter than the header.
    cut = [lines[0]] + [",".join(ln.split(",")[:5]) for ln in lines[1:]]
    path = put(tmp_path, "cut.csv", cut)
    raises(lambda: read_euroc_imu(path), str(path), "line 2", "missing 'a_RS_S_y [m s^-2]'")


def test_pose_file_given_as_imu_and_back(tmp_path: Path) -> None:
    poses = put(tmp_path, "poses.csv", pose_lines(tmp_path))
    raises(lambda: read_euroc_imu(poses), str(poses), "EuRoC pose file", "--mocap")
    imu = put(tmp_path, "imu.csv", imu_lines(tmp_path))
    raises(lambda: read_euroc_poses(imu), str(imu), "EuRoC IMU file", "--imu")
    raises(lambda: load_inputs(poses, poses, None), str(poses), "holds only poses")
    raises(lambda: load_inputs(poses, imu, None), str(poses), "--imu is given a pose file",
           "--mocap")


def test_unparseable_values(tmp_path: Path) -> None:
    lines = imu_lines(tmp_path)
    set_field(lines, 57, 3, "abc")
    path = put(tmp_path, "bad.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "line 57", "'w_RS_S_z [rad s^-1]'",
           "'abc'", "not a number", "fix or delete")
    lines = imu_lines(tmp_path)
    set_field(lines, 9, 0, "12x4")
    path = put(tmp_path, "badtime.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "line 9", "'12x4'", "not a number")
    lines = imu_lines(tmp_path)
    lines[20] += ",1.0"
    path = put(tmp_path, "extra.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "line 21", "same columns")


def test_line_numbers_skip_comments_and_blank_lines(tmp_path: Path) -> None:
    lines = imu_lines(tmp_path)
    set_field(lines, 30, 5, "nan")
    lines[10:10] = ["# operator note", ""]  # the bad row moves to line 32
    path = put(tmp_path, "commented.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "line 32", "NaN", "fix or delete")


# --- values ----------------------------------------------------------------------------------

def test_nan_and_inf_in_imu(tmp_path: Path) -> None:
    for value in ("nan", "inf", ""):
        lines = imu_lines(tmp_path)
        set_field(lines, 101, 4, value)
        path = put(tmp_path, "nan_imu.csv", lines)
        raises(lambda p=path: read_euroc_imu(p), str(path), "line 101", "IMU row",
               "re-export")


def test_nan_mocap_rows_are_occlusions(tmp_path: Path) -> None:
    lines = pose_lines(tmp_path)
    for line in (5, 6, 7, 50):
        set_field(lines, line, 4, "nan")
    set_field(lines, 60, 2, "nan")
    path = put(tmp_path, "occluded.csv", lines)
    m = read_euroc_poses(path)
    assert m.dropped_rows == 5 and len(m) == 95
    everything = [lines[0]] + [",".join([ln.split(",")[0]] + ["nan"] * 7) for ln in lines[1:]]
    path = put(tmp_path, "allnan.csv", everything)
    raises(lambda: read_euroc_poses(path), str(path), "every mocap row is NaN")
    lines = pose_lines(tmp_path)
    set_field(lines, 12, 1, "inf")
    path = put(tmp_path, "inf.csv", lines)
    raises(lambda: read_euroc_poses(path), str(path), "line 12", "infinite", "NaN")


def test_timestamps_not_increasing(tmp_path: Path) -> None:
    lines = imu_lines(tmp_path)
    lines[40], lines[41] = lines[41], lines[40]  # lines 41 and 42 swapped
    path = put(tmp_path, "unsorted.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "line 42", "earlier", "sort the file")
    lines = imu_lines(tmp_path)
    lines.insert(70, lines[69])  # line 71 repeats line 70
    path = put(tmp_path, "dup.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "line 71", "repeats",
           "remove duplicate rows")
    lines = pose_lines(tmp_path)
    set_field(lines, 31, 0, lines[29].split(",")[0])
    path = put(tmp_path, "dup_pose.csv", lines)
    raises(lambda: read_euroc_poses(path), str(path), "line 31", "mocap", "duplicate")


def test_quaternion_norm(tmp_path: Path) -> None:
    lines = pose_lines(tmp_path)
    parts = lines[14].split(",")
    lines[14] = ",".join(parts[:4] + [repr(float(v) * 1.01) for v in parts[4:]])
    for line in (3, 4, 9):  # occlusions before it must not shift the line named
        set_field(lines, line, 6, "nan")
    path = put(tmp_path, "badq.csv", lines)
    raises(lambda: read_euroc_poses(path), str(path), "line 15", "quaternion norm",
           "normalise")
    # Off by 5e-4: normalised silently.
    lines = pose_lines(tmp_path)
    parts = lines[14].split(",")
    lines[14] = ",".join(parts[:4] + [repr(float(v) * 1.0005) for v in parts[4:]])
    m = read_euroc_poses(put(tmp_path, "nearq.csv", lines))
    assert np.allclose(np.linalg.norm(m.quat_wxyz, axis=1), 1.0, atol=1e-15)
    # A zero quaternion (a dropout written as zeros) names the line.
    lines = pose_lines(tmp_path)
    for f in range(4, 8):
        set_field(lines, 20, f, "0")
    path = put(tmp_path, "zeroq.csv", lines)
    raises(lambda: read_euroc_poses(path), str(path), "line 20", "not zeros")


# --- units -----------------------------------------------------------------------------------

def test_accel_in_g(tmp_path: Path) -> None:
    imu = make_imu()
    g = ImuSamples(imu.t, imu.gyro, imu.accel / 9.80665, imu.time_origin_ns)
    path = write_euroc_imu(tmp_path / "g.csv", g)
    raises(lambda: read_euroc_imu(path), str(path), "--accel-unit g")
    back = read_euroc_imu(path, accel_unit="g")
    assert np.allclose(back.accel, imu.accel, rtol=1e-14)
    raises(lambda: read_euroc_imu(write_euroc_imu(tmp_path / "ms2.csv", imu), accel_unit="g"),
           "--accel-unit m/s^2")


def test_gyro_in_deg_per_s(tmp_path: Path) -> None:
    imu = make_imu()
    fast = ImuSamples(imu.t, 30.0 * imu.gyro, imu.accel, imu.time_origin_ns)  # ~6 rad/s
    deg = ImuSamples(imu.t, np.degrees(fast.gyro), imu.accel, imu.time_origin_ns)
    path = write_euroc_imu(tmp_path / "deg.csv", deg)
    raises(lambda: read_euroc_imu(path), str(path), "--gyro-unit deg/s")
    assert np.allclose(read_euroc_imu(path, gyro_unit="deg/s").gyro, fast.gyro, rtol=1e-14)
    # A gyro that never goes quiet (5th percentile above 3 "rad/s") is also flagged.
    spin = ImuSamples(imu.t, np.full((len(imu), 3), [0.0, 0.0, 5.0]) + imu.gyro, imu.accel,
                      imu.time_origin_ns)
    path = write_euroc_imu(tmp_path / "spin.csv", spin)
    raises(lambda: read_euroc_imu(path), "--gyro-unit deg/s")


def test_positions_in_mm(tmp_path: Path) -> None:
    m = make_mocap()
    mm = MocapPoses(m.t, m.quat_wxyz, m.position * 1000.0, m.time_origin_ns)
    path = write_euroc_poses(tmp_path / "mm.csv", mm)
    raises(lambda: read_euroc_poses(path), str(path), "--position-unit mm")
    tum = write_tum(tmp_path / "mm.txt", mm)
    raises(lambda: read_tum(tum), str(tum), "--position-unit mm")
    assert np.allclose(read_tum(tum, position_unit="mm").position, m.position, rtol=1e-14)


def test_wrong_time_unit(tmp_path: Path) -> None:
    # EuRoC layout but microsecond stamps: 5000 "ns" steps look like 200 kHz.
    lines = imu_lines(tmp_path)
    for k in range(2, len(lines) + 1):
        set_field(lines, k, 0, str((T0_NS + (k - 2) * 5_000_000) // 1000))
    path = put(tmp_path, "us.csv", lines)
    raises(lambda: read_euroc_imu(path), str(path), "look like us", "--time-unit us")
    assert abs(read_euroc_imu(path, time_unit="us").rate_hz - 200.0) < 1e-6
    # Generic CSV with ms stamps read as seconds: 5 s steps.
    rows = [f"{5 * k},0.01,0.02,0.03,0.1,0.2,9.8" for k in range(200)]
    path = put(tmp_path, "ms.csv", rows)
    raises(lambda: read_generic(path, "t=0,gyro=1:4,accel=4:7"), str(path), "--time-unit ms")


def test_imu_gap_is_read_not_refused(tmp_path: Path) -> None:
    lines = imu_lines(tmp_path)
    del lines[150:160]  # ten samples missing after data row 148
    path = put(tmp_path, "gap.csv", lines)
    imu = read_euroc_imu(path)  # the calibration handles gaps (core/policy.py), not the reader
    assert len(imu) == len(lines) - 1 and np.isclose(imu.t[149] - imu.t[148], 11 * 0.005)


def test_too_few_rows(tmp_path: Path) -> None:
    path = put(tmp_path, "few.csv", imu_lines(tmp_path)[:60])
    raises(lambda: read_euroc_imu(path), str(path), "only 59 usable IMU rows", "at least 100",
           "longer session")
    path = put(tmp_path, "fewpose.csv", pose_lines(tmp_path)[:15])
    raises(lambda: read_euroc_poses(path), str(path), "only 14 usable mocap rows", "at least 20")
    # Counting usable rows: 25 poses, 10 of them occluded.
    lines = pose_lines(tmp_path)[:26]
    for k in range(2, 12):
        set_field(lines, k, 5, "nan")
    path = put(tmp_path, "occl.csv", lines)
    raises(lambda: read_euroc_poses(path), "only 15 usable mocap rows (10 NaN rows dropped")


# --- formats, options ---------------------------------------------------------------------------

def test_tum_wrong_column_count(tmp_path: Path) -> None:
    path = put(tmp_path, "seven.txt", [f"{k}.0 1 2 3 0 0 1" for k in range(30)])
    raises(lambda: read_tum(path), str(path), "line 1", "8", "--columns")


def test_generic_needs_columns(tmp_path: Path) -> None:
    rows = ["t,gx,gy,gz,ax,ay,az,qw,qx,qy,qz,px,py,pz"]
    rows += [f"{k * 0.005:.3f},0.1,0,0,0,0,9.8,1,0,0,0,0,0,0" for k in range(200)]
    path = put(tmp_path, "log.csv", rows)
    raises(lambda: load_inputs(path, path, None), str(path), "--columns")
    imu, mocap, _ = load_inputs(path, path, None, columns="t=0,gyro=1:4,accel=4:7,quat=7:11,"
                                "pos=11:14")
    assert len(imu) == 200 and len(mocap) == 200
    raises(lambda: read_generic(path, "t=0,gyro=gx|gy|gq,accel=4:7"), str(path), "'gq'",
           "line 1", "header name")
    raises(lambda: read_generic(path, "t=0,gyro=1:4,accel=4:7", streams=["mocap"]),
           "--columns", "quat=")
    raises(lambda: read_generic(path, "t=0,gyro=20:23,accel=4:7"), str(path), "column 20",
           "--columns")
    headerless = put(tmp_path, "nohead.csv", rows[1:])
    raises(lambda: read_generic(headerless, "t=t,gyro=1:4,accel=4:7"), str(headerless),
           "no header line", "0-based")


@pytest.mark.parametrize("spec,part", [
    ("t=0,gyro=1:3,accel=4:7", "gyro= names 2 columns"),
    ("t=0,gyro=1:4", "needs both gyro= and accel="),
    ("t=0,quat=1:5", "needs both quat= and pos="),
    ("gyro=1:4,accel=4:7", "no time column"),
    ("t=0,t=1", "given twice"),
    ("t=0,mag=1:4", "cannot read 'mag=1:4'"),
    ("t=0,gyro=1||3,accel=4:7", "empty column"),
])
def test_parse_columns_errors(spec: str, part: str) -> None:
    raises(lambda: parse_columns(spec), "--columns", part, "0-based")


def test_bad_options(tmp_path: Path) -> None:
    path = put(tmp_path, "imu.csv", imu_lines(tmp_path))
    raises(lambda: read_euroc_imu(path, gyro_unit="rpm"), "--gyro-unit", "'rpm'", "deg/s")
    raises(lambda: read_euroc_imu(path, time_unit="min"), "--time-unit", "ns")
    root = write_mav0(tmp_path / "s", make_imu(), make_mocap())
    raises(lambda: read_mav0(root, pose_source="optitrack"), "--pose-source", "groundtruth")
    raises(lambda: read_mav0(root, pose_source="groundtruth"),
           "state_groundtruth_estimate0/data.csv", "--pose-source")
    raises(lambda: read_mav0(tmp_path), str(tmp_path), "no EuRoC mav0 folder")
    raises(lambda: load_inputs(path, None, None), "no --mocap given", "--mav0")
    raises(lambda: load_inputs(path, None, root), "--mav0 and --imu/--mocap")
    (root / "vicon0" / "sensor.yaml").write_text("T_BS:\n  data: [1, 2, 3]\n")
    raises(lambda: read_mav0(root), "sensor.yaml", "T_BS is not a 4x4 matrix")
