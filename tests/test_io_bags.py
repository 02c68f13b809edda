"""Bags and logs in: ROS 1, ROS 2 (db3, MCAP), bare MCAP and PX4 ULog give the CSV's numbers.

Each recording is written from the very samples the session's EuRoC CSVs hold (read back from
them), so a calibration on the recording must give the CSV's result to 1e-9. The ULog holds
float32 values and microsecond stamps, as PX4 logs them: its session's CSV is written from the
same float32-rounded values (mocap turned from NED into the z-up world by hand).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mocap_calib.cli.main import main
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.io.formats.euroc import write_mav0
from mocap_calib.io.loader import load_inputs, sniff_format
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.workflows.calibrate import CalibrateRequest, InputSpec, run_calibration
from mocap_calib.workflows.imu.imu_input import ImuSpec
from mocap_calib.workflows.session import MocapFormat

sys.path.insert(0, str(Path(__file__).parent))
from recordings import write_bag, write_ulog  # noqa: E402

POSE_TYPES = ["geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped",
              "geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"]


@pytest.fixture(scope="module")
def csv_session(tmp_path_factory) -> tuple[Path, ImuSamples, MocapPoses]:
    """A 40 s session as EuRoC CSVs, and the streams as read back from them."""
    sim = simulate_flight(SimConfig(seed=5, duration=40.0, effects={"time_offset": [0.004]}))
    root = write_mav0(tmp_path_factory.mktemp("bags") / "s", sim.imu, sim.mocap)
    imu, mocap, _ = load_inputs(None, None, root)
    return root, imu, mocap


def _calibrate(spec: InputSpec) -> dict:
    result, _ = run_calibration(CalibrateRequest(inputs=spec, options=CalibrationOptions()))
    d = result.to_dict()
    return {k: d[k] for k in ("gyro_bias", "accel_bias", "T_marker_imu", "gravity_in_mocap",
                              "time_offset", "sigma")}


def _flat(x) -> list[float]:
    if isinstance(x, dict):
        return [v for k in sorted(x) for v in _flat(x[k])]
    if isinstance(x, list):
        return [v for e in x for v in _flat(e)]
    return [float(x)]


@pytest.fixture(scope="module")
def csv_result(csv_session) -> dict:
    root = csv_session[0]
    return _calibrate(InputSpec(imu=root / "imu0/data.csv", mocap=root / "vicon0/data.csv"))


@pytest.mark.slow  # full calibrations: in the whole suite, not the quick subset
@pytest.mark.parametrize("kind,name", [("rosbag1", "s.bag"), ("db3", "s_db3"),
                                       ("mcap", "s_mcap"), ("bare_mcap", "s.mcap")])
def test_calibrate_on_a_bag_gives_the_csv_numbers(kind, name, csv_session, csv_result,
                                                  tmp_path) -> None:
    _, imu, mocap = csv_session
    bag = write_bag(tmp_path / name, kind, imu, mocap,
                    extra_topics={"/tf_static": "tf2_msgs/msg/TFMessage"})
    assert sniff_format(bag) == ("rosbag1" if kind == "rosbag1" else
                                 "mcap" if kind == "bare_mcap" else "rosbag2")
    got = _calibrate(InputSpec(imu=bag, mocap=bag))
    np.testing.assert_allclose(_flat(got), _flat(csv_result), rtol=0, atol=1e-9)


@pytest.mark.parametrize("pose_type", POSE_TYPES)
def test_every_pose_type_gives_the_same_poses(pose_type, csv_session, tmp_path) -> None:
    _, imu, mocap = csv_session
    bag = write_bag(tmp_path / "p.bag", "rosbag1", None, mocap, pose_type=pose_type)
    _, got, _ = load_inputs(*_two(csv_session[0], bag))
    assert np.array_equal(got.stamps_ns(), mocap.stamps_ns())
    assert np.array_equal(got.position, mocap.position)
    assert np.array_equal(got.quat_wxyz, mocap.quat_wxyz)


def _two(root: Path, mocap: Path) -> tuple[Path, Path, None]:
    return root / "imu0/data.csv", mocap, None


def test_tf_topic_with_child_frame_and_receive_stamps(csv_session, tmp_path) -> None:
    from mocap_calib.io.formats.bags import RecordingOptions

    _, imu, mocap = csv_session
    bag = write_bag(tmp_path / "tf_db3", "db3", imu, mocap, pose_type="tf2_msgs/msg/TFMessage",
                    mocap_topic="/tf", receive_delay_ns=2_500_000)
    got_imu, got, notes = load_inputs(bag, bag, None, recording=RecordingOptions(
        mocap_frame="drone", stamp="receive"))
    assert np.array_equal(got.position, mocap.position)
    assert np.array_equal(got.stamps_ns(), mocap.stamps_ns() + 2_500_000)
    assert np.array_equal(got_imu.stamps_ns(), imu.stamps_ns() + 2_500_000)
    assert any("ROS 2 bag" in n for n in notes)


def test_imu_only_commands_read_bags_and_ulogs(csv_session, tmp_path) -> None:
    _, imu, _ = csv_session
    bag = write_bag(tmp_path / "imu.mcap", "bare_mcap", imu, None)
    got, notes = ImuSpec(imu=bag).load()
    assert np.array_equal(got.gyro, imu.gyro) and np.array_equal(got.t, imu.t)
    assert any("MCAP" in n for n in notes)


# --- PX4 ULog --------------------------------------------------------------------------------

def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    axis=-1)


@pytest.fixture(scope="module")
def px4_session(tmp_path_factory):
    """Float32 IMU in FRD and float32 mocap poses in NED, plus the same session as CSVs with
    the mocap world turned z-up (ENU: x = east = y_NED, y = north = x_NED, z = -z_NED)."""
    sim = simulate_flight(SimConfig(seed=8, duration=40.0, effects={"time_offset": [0.006]}))
    f32 = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
    imu = ImuSamples(sim.imu.t, f32(sim.imu.gyro), f32(sim.imu.accel), sim.imu.time_origin_ns)
    # Take the simulator's z-up world as ENU; PX4 would log it as NED.
    q_ne = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])  # R_NED_ENU: x<->y, z -> -z
    q_ned = f32(_quat_mul(q_ne, sim.mocap.quat_wxyz))
    p_enu = sim.mocap.position
    p_ned = f32(np.stack([p_enu[:, 1], p_enu[:, 0], -p_enu[:, 2]], axis=1))
    t_us = np.round(sim.mocap.t * 1e6) / 1e6
    ned = MocapPoses(t_us, q_ned, p_ned, sim.mocap.time_origin_ns)
    folder = tmp_path_factory.mktemp("px4")
    ulg = write_ulog(folder / "flight.ulg", imu, ned)
    q_back = _quat_mul(q_ne * np.array([1, -1, -1, -1]), q_ned)  # R_ENU_NED R_NED_M
    q_back /= np.linalg.norm(q_back, axis=1, keepdims=True)
    enu = MocapPoses(t_us, q_back, np.stack([p_ned[:, 1], p_ned[:, 0], -p_ned[:, 2]], axis=1),
                     sim.mocap.time_origin_ns)
    root = write_mav0(folder / "csv", imu, enu)
    return ulg, root


@pytest.mark.slow  # full calibrations: in the whole suite, not the quick subset
def test_calibrate_on_a_ulog_gives_the_csv_numbers(px4_session) -> None:
    ulg, root = px4_session
    csv = _calibrate(InputSpec(imu=root / "imu0/data.csv", mocap=root / "vicon0/data.csv"))
    got = _calibrate(InputSpec(imu=ulg, mocap=ulg))
    np.testing.assert_allclose(_flat(got), _flat(csv), rtol=0, atol=1e-9)
    # The z-up world: gravity along -z, as for every other input.
    assert got["gravity_in_mocap"][2] < -0.99


def test_ulog_accel_logged_apart_from_the_gyro_is_interpolated(px4_session, tmp_path) -> None:
    from mocap_calib.io.formats.ulog import read_ulog_imu

    ulg, root = px4_session
    imu, _, _ = load_inputs(root / "imu0/data.csv", root / "vicon0/data.csv", None)
    shifted = write_ulog(tmp_path / "rel.ulg", imu, None, accel_relative_us=2500)
    notes: list[str] = []
    got = read_ulog_imu(shifted, None, notes)
    # Accel sample k is now at t_k + 2.5 ms: interpolated back onto t_k it is the mean of
    # samples k-1 and k. The first gyro sample has no accel sample before it: left out, not
    # extrapolated.
    assert np.array_equal(got.stamps_ns(), imu.stamps_ns()[1:])
    np.testing.assert_allclose(got.accel, 0.5 * (imu.accel[1:] + imu.accel[:-1]), atol=1e-6)
    assert any("interpolated" in n and "1 gyro samples" in n for n in notes)


# --- bad input: one line naming the file and the fix, no traceback ---------------------------

def _one_line(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [x for x in err.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    assert "Traceback" not in err
    return lines[0]


def _cal(args: list[str], tmp_path: Path) -> int:
    return main(["calibrate", *args, "--out", str(tmp_path / "o.yaml"), "-q"])


def test_bad_bags_and_logs(csv_session, tmp_path, capsys) -> None:
    root, imu, mocap = csv_session
    csv = str(root / "imu0/data.csv")
    good = write_bag(tmp_path / "g.bag", "rosbag1", imu, mocap, mocap_topic="/vicon/a",
                     extra_topics={"/vicon/b": "geometry_msgs/msg/PoseStamped"})
    # A topic that is not in the bag.
    line = _one_line(capsys, _cal(["--imu", str(good), "--mocap", str(good), "--mocap-topic",
                                   "/nope"], tmp_path))
    assert "g.bag" in line and "/nope" in line and "--mocap-topic" in line
    # Two candidate pose topics: the line lists them.
    line = _one_line(capsys, _cal(["--imu", str(good), "--mocap", str(good)], tmp_path))
    assert "/vicon/a" in line and "/vicon/b" in line and "--mocap-topic" in line
    # A topic of the wrong type.
    line = _one_line(capsys, _cal(["--imu", str(good), "--mocap", str(good), "--imu-topic",
                                   "/vicon/a"], tmp_path))
    assert "PoseStamped" in line and "--imu-topic" in line and "/imu0" in line
    # An empty bag.
    empty = write_bag(tmp_path / "empty.bag", "rosbag1", None, None)
    line = _one_line(capsys, _cal(["--imu", str(empty), "--mocap", csv], tmp_path))
    assert "empty.bag" in line and "no messages" in line
    # Truncated bags of every container and a truncated ULog.
    for name, kind in (("t.bag", "rosbag1"), ("t.mcap", "bare_mcap")):
        full = write_bag(tmp_path / name, kind, imu, mocap)
        data = full.read_bytes()
        full.write_bytes(data[: len(data) // 2])
        line = _one_line(capsys, _cal(["--imu", str(full), "--mocap", str(full),
                                       "--mocap-topic", "/vicon/drone/pose"], tmp_path))
        assert name in line and "truncated" in line
    folder = write_bag(tmp_path / "t_db3", "db3", imu, mocap)
    db3 = next(folder.glob("*.db3"))
    db3.write_bytes(db3.read_bytes()[:4096])
    line = _one_line(capsys, _cal(["--imu", str(folder), "--mocap", str(folder)], tmp_path))
    assert "t_db3" in line and "truncated" in line
    ulg = write_ulog(tmp_path / "t.ulg", imu, None)
    ulg.write_bytes(ulg.read_bytes()[:-7])
    line = _one_line(capsys, main(["allan", "--imu", str(ulg), "--out",
                                   str(tmp_path / "n.yaml"), "-q"]))
    assert "t.ulg" in line and "truncated" in line
    # A ULog without mocap odometry.
    ulg = write_ulog(tmp_path / "imu_only.ulg", imu, None)
    line = _one_line(capsys, _cal(["--imu", str(ulg), "--mocap", str(ulg)], tmp_path))
    assert "imu_only.ulg" in line and "vehicle_mocap_odometry" in line
    # TF without a child frame: the line lists the frames.
    tf = write_bag(tmp_path / "tf.bag", "rosbag1", imu, mocap, mocap_topic="/tf",
                   pose_type="tf2_msgs/msg/TFMessage")
    line = _one_line(capsys, _cal(["--imu", str(tf), "--mocap", str(tf)], tmp_path))
    assert "--mocap-frame" in line and "drone" in line and "other_body" in line


def test_run_calibration_accepts_bag_options(csv_session, csv_result, tmp_path) -> None:
    _, imu, mocap = csv_session
    bag = write_bag(tmp_path / "o.bag", "rosbag1", imu, mocap, mocap_topic="/a",
                    extra_topics={"/b": "nav_msgs/msg/Odometry"})
    spec = InputSpec(imu=bag, mocap=bag, poses=MocapFormat(mocap_topic="/a"))
    np.testing.assert_allclose(_flat(_calibrate(spec)), _flat(csv_result), rtol=0, atol=1e-9)
