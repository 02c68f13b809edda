"""Readers and writers: exact round trips, determinism, real EuRoC and BROAD files, sniffing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError
from mocap_calib.io.formats.columns import BROAD, ColumnMap, parse_columns
from mocap_calib.io.formats.euroc import (
    IMU_HEADER,
    POSE_HEADER,
    read_euroc_imu,
    read_euroc_poses,
    read_mav0,
    write_euroc_imu,
    write_euroc_poses,
    write_mav0,
)
from mocap_calib.io.formats.generic import read_generic
from mocap_calib.io.formats.tum import read_tum, write_tum
from mocap_calib.io.loader import load_inputs, sniff_format
from mocap_calib.io.validate import check_overlap

T0_NS = 1_413_394_881_575_760_384  # an EuRoC-like epoch stamp


def make_imu(n: int = 400, rate: float = 200.0, seed: int = 0) -> ImuSamples:
    """A plausible IMU stream on an integer-ns grid with a little jitter."""
    rng = np.random.default_rng(seed)
    ns = T0_NS + np.round(np.arange(n) * 1e9 / rate).astype(np.int64) + rng.integers(-500, 500, n)
    ns[0] = T0_NS
    t = (ns - T0_NS) / 1e9
    gyro = 0.3 * np.sin(np.outer(t, [1.0, 2.0, 3.0])) + 1e-3 * rng.normal(size=(n, 3))
    accel = np.array([0.1, -0.2, 9.81]) + 0.5 * rng.normal(size=(n, 3))
    return ImuSamples(t, gyro, accel, T0_NS, "synthetic")


def make_mocap(n: int = 200, rate: float = 100.0, seed: int = 1) -> MocapPoses:
    """Plausible poses: unit quaternions (some with w < 0) and positions in a 3 m room."""
    rng = np.random.default_rng(seed)
    ns = T0_NS + np.round(np.arange(n) * 1e9 / rate).astype(np.int64) + 123
    q = so3.rotmat_to_quat(so3.exp(rng.normal(size=(n, 3))))
    q[::3] *= -1.0
    pos = rng.uniform(-1.5, 1.5, size=(n, 3))
    return MocapPoses((ns - ns[0]) / 1e9, q, pos, int(ns[0]), "synthetic")


def canonical(q: np.ndarray) -> np.ndarray:
    return np.where(q[:, :1] < 0, -q, q)


def assert_imu_equal(a: ImuSamples, b: ImuSamples) -> None:
    assert np.array_equal(a.stamps_ns(), b.stamps_ns())
    assert a.time_origin_ns == b.time_origin_ns
    assert np.array_equal(a.t, b.t)
    assert np.array_equal(a.gyro, b.gyro)
    assert np.array_equal(a.accel, b.accel)


def assert_mocap_equal(a: MocapPoses, b: MocapPoses) -> None:
    assert np.array_equal(a.stamps_ns(), b.stamps_ns())
    assert a.time_origin_ns == b.time_origin_ns
    assert np.array_equal(a.t, b.t)
    assert np.array_equal(canonical(a.quat_wxyz), canonical(b.quat_wxyz))
    assert np.array_equal(a.position, b.position)


# --- round trips ------------------------------------------------------------------------------

def test_euroc_imu_round_trip_and_determinism(tmp_path: Path) -> None:
    imu = make_imu()
    p1 = write_euroc_imu(tmp_path / "a" / "data.csv", imu)
    p2 = write_euroc_imu(tmp_path / "b" / "data.csv", imu)
    assert p1.read_bytes() == p2.read_bytes()
    assert p1.read_text().splitlines()[0] == IMU_HEADER
    back = read_euroc_imu(p1)
    assert_imu_equal(back, imu)
    assert back.source == str(p1)
    write_euroc_imu(tmp_path / "c.csv", back)
    assert (tmp_path / "c.csv").read_bytes() == p1.read_bytes()


def test_euroc_poses_round_trip_and_determinism(tmp_path: Path) -> None:
    mocap = make_mocap()
    p1 = write_euroc_poses(tmp_path / "a.csv", mocap)
    p2 = write_euroc_poses(tmp_path / "b.csv", mocap)
    assert p1.read_bytes() == p2.read_bytes()
    assert p1.read_text().splitlines()[0] == POSE_HEADER
    back = read_euroc_poses(p1)
    assert_mocap_equal(back, mocap)
    assert (back.quat_wxyz[:, 0] >= 0).all()  # written with w >= 0
    assert back.dropped_rows == 0


def test_mav0_round_trip(tmp_path: Path) -> None:
    imu, mocap = make_imu(), make_mocap()
    root = write_mav0(tmp_path / "session", imu, mocap)
    assert root == tmp_path / "session" / "mav0"
    assert (root / "imu0" / "data.csv").is_file() and (root / "vicon0" / "data.csv").is_file()
    for path in (tmp_path / "session", root):
        m = read_mav0(path)
        assert m.pose_source == "vicon0" and m.T_imu_marker is None and m.root == root
        assert_imu_equal(m.imu, imu)
        assert_mocap_equal(m.mocap, mocap)
    again = write_mav0(tmp_path / "again", imu, mocap)
    for sub in ("imu0", "vicon0"):
        assert (again / sub / "data.csv").read_bytes() == (root / sub / "data.csv").read_bytes()


def test_mav0_reads_t_bs(tmp_path: Path) -> None:
    root = write_mav0(tmp_path, make_imu(), make_mocap())
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    (root / "vicon0" / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: pose\nT_BS:\n  cols: 4\n  rows: 4\n  data: ["
        + ", ".join(map(str, T.ravel())) + "]\n")
    assert np.array_equal(read_mav0(tmp_path, "vicon0").T_imu_marker, T)


def test_tum_round_trip_keeps_nanoseconds(tmp_path: Path) -> None:
    mocap = make_mocap()
    p1 = write_tum(tmp_path / "a.txt", mocap)
    p2 = write_tum(tmp_path / "b.txt", mocap)
    assert p1.read_bytes() == p2.read_bytes()
    first = p1.read_text().splitlines()[1].split()
    assert first[0] == f"{mocap.time_origin_ns // 10**9}.{mocap.time_origin_ns % 10**9:09d}"
    assert len(first) == 8
    back = read_tum(p1)
    assert_mocap_equal(back, mocap)


def test_tum_reads_comments_and_xyzw(tmp_path: Path) -> None:
    path = tmp_path / "traj.txt"
    rows = [f"{1.5 + 0.01 * k:.2f} {k * 0.01} 0 1  0 0 0.6 0.8" for k in range(30)]
    path.write_text("# a comment\n# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows[:10])
                    + "\n# mid-file comment\n\n" + "\n".join(rows[10:]) + "\n")
    m = read_tum(path)
    assert len(m) == 30 and m.time_origin_ns == 1_500_000_000
    assert np.allclose(m.quat_wxyz, [0.8, 0.0, 0.0, 0.6])
    assert np.array_equal(m.stamps_ns()[:3], [1_500_000_000, 1_510_000_000, 1_520_000_000])


# --- generic reader ------------------------------------------------------------------------

def test_parse_columns_forms() -> None:
    cm = parse_columns("t=0,gyro=1:4,accel=4:7,quat=10:14,pos=14:17")
    assert cm == ColumnMap(0, (1, 2, 3), (4, 5, 6), (10, 11, 12, 13), (14, 15, 16))
    assert parse_columns(" broad ") == BROAD
    named = parse_columns("time=t [s], gyr=gyr_x|gyr_y|gyr_z, acc=3|4|5")
    assert named.time == "t [s]" and named.gyro == ("gyr_x", "gyr_y", "gyr_z")
    assert named.accel == (3, 4, 5) and not named.has_mocap and named.has_imu


def test_generic_units_delimiters_and_orders(tmp_path: Path) -> None:
    imu, mocap = make_imu(n=300), make_mocap(n=300, rate=200.0)
    # ms stamps with 6 decimals (exact ns), deg/s, g, xyzw, mm, semicolon-delimited.
    ns = imu.stamps_ns()
    t_ms = [f"{v // 10**6}.{v % 10**6:06d}" for v in ns.tolist()]
    q = mocap.quat_wxyz
    gyro, accel = np.degrees(imu.gyro).tolist(), (imu.accel / 9.80665).tolist()
    quat, pos = q[:, [1, 2, 3, 0]].tolist(), (mocap.position * 1e3).tolist()
    rows = [";".join([t_ms[k], *map(repr, gyro[k]), *map(repr, accel[k]), "7",
                      *map(repr, quat[k]), *map(repr, pos[k])]) for k in range(300)]
    path = tmp_path / "log.csv"
    path.write_text("time_ms;gx;gy;gz;ax;ay;az;flag;qx;qy;qz;qw;px;py;pz\n" + "\n".join(rows))
    got_imu, got_mocap = read_generic(
        path, "t=time_ms,gyro=1:4,accel=ax|AY|az,quat=8:12,pos=px|py|pz", time_unit="ms",
        gyro_unit="deg/s", accel_unit="g", quat_order="xyzw", position_unit="mm")
    assert got_imu is not None and got_mocap is not None
    assert np.array_equal(got_imu.stamps_ns(), ns)
    assert np.allclose(got_imu.gyro, imu.gyro, rtol=1e-12, atol=0)
    assert np.allclose(got_imu.accel, imu.accel, rtol=1e-12, atol=0)
    assert np.allclose(got_mocap.quat_wxyz, q, atol=1e-15)
    assert np.allclose(got_mocap.position, mocap.position, rtol=1e-12, atol=0)
    # Asking for one stream reads only that one.
    only_imu, none = read_generic(path, "t=0,gyro=1:4,accel=4:7", time_unit="ms",
                                  gyro_unit="deg/s", accel_unit="g")
    assert none is None and only_imu is not None and len(only_imu) == 300


def test_generic_whitespace_headerless_matches_euroc(tmp_path: Path) -> None:
    imu = make_imu()
    path = write_euroc_imu(tmp_path / "imu.csv", imu)
    body = path.read_text().splitlines()[1:]
    ws = tmp_path / "imu.txt"
    ws.write_text("\n".join(line.replace(",", "  ") for line in body) + "\n")
    got, _ = read_generic(ws, "t=0,gyro=1:4,accel=4:7", time_unit="ns")
    assert got is not None
    assert_imu_equal(got, imu)


def test_generic_decimal_comma(tmp_path: Path) -> None:
    rows = ["zeit;gx;gy;gz;ax;ay;az"]
    rows += [f"{k * 0.005:.3f};0.01;0;{k % 3};0.1;0.2;9.81".replace(".", ",") for k in range(200)]
    path = tmp_path / "export.csv"
    path.write_text("\n".join(rows) + "\n")
    imu, _ = read_generic(path, "t=zeit,gyro=gx|gy|gz,accel=4:7")
    assert imu is not None
    assert np.array_equal(imu.stamps_ns(), np.arange(200) * 5_000_000)
    assert np.array_equal(imu.accel[0], [0.1, 0.2, 9.81]) and imu.gyro[2, 2] == 2.0


def test_broad_preset_counts(broad21_csv: Path) -> None:
    raw = np.loadtxt(broad21_csv, delimiter=",", skiprows=1)
    nan_quat_rows = int(np.isnan(raw[:, 10:14]).any(axis=1).sum())
    assert nan_quat_rows > 0
    imu, mocap = read_generic(broad21_csv, BROAD)
    assert imu is not None and mocap is not None
    assert len(imu) == len(raw)
    assert mocap.dropped_rows == nan_quat_rows
    assert len(mocap) == len(raw) - nan_quat_rows
    assert np.array_equal(imu.gyro, raw[:, 1:4]) and np.array_equal(imu.accel, raw[:, 4:7])
    good = ~np.isnan(raw[:, 10:17]).any(axis=1)
    assert np.array_equal(mocap.position, raw[good, 14:17])
    # Float seconds become exact integer ns (0.0035 s steps -> 3_500_000 ns).
    assert imu.time_origin_ns == 0 and np.all(np.diff(imu.stamps_ns()) == 3_500_000)
    assert mocap.stamps_ns()[0] == round(raw[good, 0][0] * 1e9)
    # The same map spelled as a --columns string, by header names and by index.
    by_name = parse_columns("t=t [s],gyro=gyr_x|gyr_y|gyr_z,accel=acc_x|acc_y|acc_z,"
                            "quat=opt_qw|opt_qx|opt_qy|opt_qz,pos=opt_px|opt_py|opt_pz")
    by_index = "t=0,gyro=1:4,accel=4:7,quat=10:14,pos=14:17"
    for cm in (by_name, by_index):
        i2, m2 = read_generic(broad21_csv, cm)
        assert i2 is not None and m2 is not None
        assert_imu_equal(i2, imu)
        assert_mocap_equal(m2, mocap)


# --- real EuRoC data ---------------------------------------------------------------------------

def _data_rows(path: Path) -> int:
    with open(path) as f:
        return sum(1 for line in f if line.strip() and not line.startswith("#"))


def test_real_mav0_both_pose_sources(euroc_dir: Path) -> None:
    mav0 = euroc_dir / "mav0"
    vicon = read_mav0(euroc_dir)
    assert vicon.pose_source == "vicon0" and vicon.root == mav0
    assert len(vicon.imu) == _data_rows(mav0 / "imu0" / "data.csv")
    assert len(vicon.mocap) == _data_rows(mav0 / "vicon0" / "data.csv")
    assert vicon.mocap.dropped_rows == 0
    first = (mav0 / "imu0" / "data.csv").read_text().splitlines()[1].split(",")
    assert vicon.imu.time_origin_ns == int(first[0])
    assert vicon.imu.gyro[0, 0] == float(first[1]) and vicon.imu.accel[0, 2] == float(first[6])
    assert abs(vicon.imu.rate_hz - 200.0) < 0.1 and abs(vicon.mocap.rate_hz - 100.0) < 0.5
    assert vicon.T_imu_marker is not None and vicon.T_imu_marker.shape == (4, 4)
    assert vicon.T_imu_marker[0, 0] == 0.33638 and vicon.T_imu_marker[2, 3] == -0.12395
    gt = read_mav0(mav0, pose_source="groundtruth")
    assert gt.pose_source == "groundtruth"
    assert len(gt.mocap) == _data_rows(mav0 / "state_groundtruth_estimate0" / "data.csv")
    assert np.array_equal(gt.T_imu_marker, np.eye(4))
    assert np.allclose(np.linalg.norm(gt.mocap.quat_wxyz, axis=1), 1.0, atol=1e-12)
    assert_imu_equal(gt.imu, vicon.imu)


def test_real_euroc_rewrites_bit_identically(euroc_dir: Path, tmp_path: Path) -> None:
    m = read_mav0(euroc_dir)
    root = write_mav0(tmp_path, m.imu, m.mocap)
    back = read_mav0(root)
    assert_imu_equal(back.imu, m.imu)
    assert_mocap_equal(back.mocap, m.mocap)
    gt = read_euroc_poses(euroc_dir / "mav0" / "state_groundtruth_estimate0" / "data.csv")
    assert_mocap_equal(read_tum(write_tum(tmp_path / "gt.txt", gt)), gt)


# --- loader ----------------------------------------------------------------------------------

def test_sniff_format(tmp_path: Path) -> None:
    imu, mocap = make_imu(), make_mocap()
    root = write_mav0(tmp_path, imu, mocap)
    assert sniff_format(tmp_path) == "mav0"
    assert sniff_format(root / "imu0" / "data.csv") == "euroc_imu"
    assert sniff_format(root / "vicon0" / "data.csv") == "euroc_poses"
    assert sniff_format(write_tum(tmp_path / "t.txt", mocap)) == "tum"
    other = tmp_path / "x.csv"
    other.write_text("a,b\n1,2\n")
    assert sniff_format(other) == "generic"


def test_load_inputs_formats(tmp_path: Path) -> None:
    imu, mocap = make_imu(), make_mocap()
    root = write_mav0(tmp_path / "s", imu, mocap)
    got_imu, got_mocap, notes = load_inputs(None, None, tmp_path / "s")
    assert_imu_equal(got_imu, imu)
    assert_mocap_equal(got_mocap, mocap)
    assert any(n.startswith("IMU: 400 samples") for n in notes)
    tum = write_tum(tmp_path / "poses.txt", mocap)
    got_imu, got_mocap, notes = load_inputs(root / "imu0" / "data.csv", tum, None)
    assert_imu_equal(got_imu, imu)
    assert_mocap_equal(got_mocap, mocap)
    assert any("TUM" in n for n in notes)
    # Same folder given as both: read as mav0.
    got_imu, _, _ = load_inputs(root, root, None)
    assert_imu_equal(got_imu, imu)
    # A generic IMU file next to EuRoC poses: the map names the IMU's columns only, so the
    # EuRoC pose file is read by its header.
    gen = tmp_path / "imu.txt"
    gen.write_text((root / "imu0" / "data.csv").read_text().split("\n", 1)[1].replace(",", " "))
    got_imu, got_mocap, notes = load_inputs(gen, root / "vicon0" / "data.csv", None,
                                            columns="t=0,gyro=1:4,accel=4:7", time_unit="ns")
    assert_imu_equal(got_imu, imu)
    assert_mocap_equal(got_mocap, mocap)
    assert not any("--columns" in n for n in notes)


def test_load_inputs_broad_same_file(broad21_csv: Path) -> None:
    imu, mocap, notes = load_inputs(broad21_csv, broad21_csv, None, columns="broad")
    assert len(imu) == 53612
    assert f"dropped {mocap.dropped_rows} mocap rows with NaN (occlusions)" in notes
    assert mocap.dropped_rows > 0


def test_check_overlap() -> None:
    imu, mocap = make_imu(), make_mocap()
    assert check_overlap(imu, mocap, allow_offset=False) > 1.0
    late = MocapPoses(mocap.t, mocap.quat_wxyz, mocap.position,
                      mocap.time_origin_ns + 3_600 * 10**9, "late.csv")
    with pytest.raises(InputError, match=r"--model base\+time_offset") as err:
        check_overlap(imu, late, allow_offset=False)
    assert "late.csv" in str(err.value) and "do not overlap" in str(err.value)
    assert check_overlap(imu, late, allow_offset=True) < -3000.0
