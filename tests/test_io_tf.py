"""ROS bags: /tf chains composed (static links from /tf_static, moving upper links interpolated),
bad chains in one line, the bulk reading's fall-back for unusual message definitions, and
``diagnose`` on a bag and on a ULog through the CLI.

Expected poses are composed with scipy's rotations, independently of the reader's quaternions.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from mocap_calib.cli.main import main
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.io.formats.bags import RecordingOptions
from mocap_calib.io.loader import load_inputs

sys.path.insert(0, str(Path(__file__).parent))
import recordings  # noqa: E402
from recordings import write_bag, write_tf_bag, write_ulog  # noqa: E402
from test_io_logs import _one_line  # noqa: E402

T0 = 1_700_000_000_000_000_000
KINDS = [("rosbag1", "c.bag"), ("bare_mcap", "c.mcap"), ("db3", "c_db3")]


def _wxyz(R: Rotation) -> np.ndarray:
    return R.as_quat()[..., [3, 0, 1, 2]]


def _R(q_wxyz) -> Rotation:
    return Rotation.from_quat(np.asarray(q_wxyz, dtype=float)[..., [1, 2, 3, 0]])


def _imu(seconds: float = 20.0) -> ImuSamples:
    rng = np.random.default_rng(2)
    n = int(seconds * 200) + 1
    t = np.arange(n) * 0.005
    return ImuSamples(t, rng.normal(0, 0.3, (n, 3)), rng.normal(0, 0.3, (n, 3)) + [0, 0, 9.81],
                      T0)


def _drone(seconds: float = 20.0) -> tuple[np.ndarray, Rotation, np.ndarray]:
    """Marker poses in the mocap's frame at 100 Hz: stamps (ns), rotations, positions."""
    t = np.arange(int(seconds * 100) + 1) * 0.01
    R = Rotation.from_rotvec(np.stack([0.4 * np.sin(0.9 * t), 0.3 * np.sin(1.3 * t),
                                       1.5 * np.sin(0.2 * t)], axis=1))
    p = np.stack([np.sin(0.5 * t), np.cos(0.4 * t), 1.0 + 0.2 * np.sin(t)], axis=1)
    return T0 + np.round(t * 1e9).astype(np.int64), R, p


R_S, P_S = Rotation.from_euler("zx", [30, 5], degrees=True), np.array([1.0, 2.0, 0.5])
R_O, P_O = Rotation.from_euler("y", 10, degrees=True), np.array([-1.0, 0.0, 0.0])


def _tf_messages(ns, R, p, static: bool = True) -> list:
    """/tf: mocap_origin -> drone and a fixed other_body; an odometry branch odom -> base_link
    at 50 Hz; /tf_static: world -> mocap_origin and world -> odom."""
    q = _wxyz(R)
    msgs = [(int(s), "/tf", [("mocap_origin", "drone", p[i], q[i]),
                             ("mocap_origin", "other_body", (0.1, 0.0, 0.0), (1, 0, 0, 0))])
            for i, s in enumerate(ns)]
    msgs += [(int(s) + 1, "/tf", [("odom", "base_link", (0.01 * i, 0.0, 0.0), (1, 0, 0, 0))])
             for i, s in enumerate(ns[::2])]
    if static:
        msgs.append((int(ns[0]) - 1, "/tf_static",
                     [("world", "mocap_origin", P_S, _wxyz(R_S)), ("world", "odom", P_O,
                                                                   _wxyz(R_O))]))
    return msgs


def _read(bag: Path, frame: str):
    return load_inputs(bag, bag, None, recording=RecordingOptions(mocap_topic="/tf",
                                                                  mocap_frame=frame))


def _same_rotations(q_wxyz: np.ndarray, R: Rotation, tol: float) -> None:
    assert np.max((_R(q_wxyz).inv() * R).magnitude()) < tol


@pytest.mark.parametrize("kind,name", KINDS)
def test_tf_chain_with_static_links(kind, name, tmp_path) -> None:
    ns, R, p = _drone()
    bag = write_tf_bag(tmp_path / name, kind, _imu(), _tf_messages(ns, R, p))
    # The root of drone's tree: world.
    _, got, notes = _read(bag, "drone")
    assert np.array_equal(got.stamps_ns(), ns)
    np.testing.assert_allclose(got.position, P_S + R_S.apply(p), rtol=0, atol=1e-12)
    _same_rotations(got.quat_wxyz, R_S * R, 1e-12)
    assert any("composed along world -> mocap_origin -> drone (with /tf_static)" in x
               for x in notes)
    assert _read(bag, "/world:/drone")[1].position.tobytes() == got.position.tobytes()
    # The mocap's own frame: the recorded values, bit for bit.
    _, own, _ = _read(bag, "mocap_origin:drone")
    assert np.array_equal(own.position, p) and np.array_equal(own.quat_wxyz, _wxyz(R))
    # A frame beside the chain: through the common ancestor world.
    _, odom, _ = _read(bag, "odom:drone")
    np.testing.assert_allclose(odom.position, R_O.inv().apply(P_S + R_S.apply(p) - P_O),
                               rtol=0, atol=1e-12)
    _same_rotations(odom.quat_wxyz, R_O.inv() * R_S * R, 1e-12)


@pytest.mark.parametrize("kind,name", KINDS[:2])
def test_tf_chain_with_a_moving_upper_link_is_interpolated(kind, name, tmp_path) -> None:
    ns, R, p = _drone()
    msgs = _tf_messages(ns, R, p, static=False)
    # world -> mocap_origin moves at 20 Hz from 1 s to 19 s: a constant-rate turn about z and a
    # straight line, which slerp and linear interpolation reproduce exactly between samples.
    tu = ns[100:1901:5]
    s = (tu - T0) * 1e-9
    for k, st in enumerate(tu):
        msgs.append((int(st), "/tf", [("world", "mocap_origin",
                                           (0.1 * s[k], -0.05 * s[k], 0.3),
                                           _wxyz(Rotation.from_rotvec([0, 0, 0.2 * s[k]])))]))
    bag = write_tf_bag(tmp_path / name, kind, _imu(), msgs)
    _, got, notes = _read(bag, "world:drone")
    inside = (ns >= tu[0]) & (ns <= tu[-1])
    assert np.array_equal(got.stamps_ns(), ns[inside])
    ti = (ns[inside] - T0) * 1e-9
    Ru = Rotation.from_rotvec(np.stack([0 * ti, 0 * ti, 0.2 * ti], axis=1))
    pu = np.stack([0.1 * ti, -0.05 * ti, 0.3 + 0 * ti], axis=1)
    np.testing.assert_allclose(got.position, pu + Ru.apply(p[inside]), rtol=0, atol=1e-9)
    _same_rotations(got.quat_wxyz, Ru * R[np.flatnonzero(inside)], 1e-9)
    assert any("TF link world -> mocap_origin interpolated at the drone stamps "
               f"({int((~inside).sum())} poses outside it left out)" in x for x in notes)


def _cal(bag: Path, tmp_path: Path, *extra: str) -> int:
    return main(["calibrate", "--imu", str(bag), "--mocap", str(bag), "--mocap-topic", "/tf",
                 *extra, "--out", str(tmp_path / "o.yaml"), "-q"])


def test_bad_tf_chains_get_one_line(tmp_path, capsys) -> None:
    ns, R, p = _drone()
    # No /tf_static recorded: world is not linked to drone.
    bag = write_tf_bag(tmp_path / "nostatic.bag", "rosbag1", _imu(),
                       _tf_messages(ns, R, p, static=False))
    line = _one_line(capsys, _cal(bag, tmp_path, "--mocap-frame", "world:drone"))
    assert "nostatic.bag" in line and "no TF chain links 'world' to 'drone'" in line
    assert "world is in no transform" in line and "drone's chain ends at 'mocap_origin'" in line
    assert "--mocap-frame mocap_origin:drone" in line
    line = _one_line(capsys, _cal(bag, tmp_path, "--mocap-frame", "odom:drone"))
    assert "odom's chain ends at 'odom'" in line and "'mocap_origin'" in line
    # A frame that is not a child frame: the line lists them.
    line = _one_line(capsys, _cal(bag, tmp_path, "--mocap-frame", "ghost"))
    assert "'ghost'" in line and "drone" in line and "base_link" in line
    # No frame given (/tf_static is never taken for the pose stream).
    full = write_tf_bag(tmp_path / "full.bag", "rosbag1", _imu(), _tf_messages(ns, R, p))
    line = _one_line(capsys, _cal(full, tmp_path))
    assert "--mocap-frame" in line and "drone" in line and "mocap_origin" in line
    # drone with two parents.
    msgs = _tf_messages(ns, R, p)
    msgs.append((int(ns[5]) + 3, "/tf", [("odom", "drone", (0, 0, 0), (1, 0, 0, 0))]))
    two = write_tf_bag(tmp_path / "two.bag", "rosbag1", _imu(), msgs)
    line = _one_line(capsys, _cal(two, tmp_path, "--mocap-frame", "drone"))
    assert "frame 'drone' has 2 parents" in line and "mocap_origin" in line and "odom" in line
    # Nothing moves between the frames.
    line = _one_line(capsys, _cal(full, tmp_path, "--mocap-frame", "other_body"))
    assert "constant" in line and "mocap_origin -> other_body" in line


@pytest.mark.parametrize("kind,name", KINDS[:2])
def test_unusual_definition_is_read_message_by_message(kind, name, tmp_path) -> None:
    """A PoseStamped recorded with an extra field: the bulk layout does not fit, the
    messages are deserialised one by one (and give the right poses)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from mocap_calib.io.formats.bags import open_bag, read_bag_mocap
    from mocap_calib.io.formats.ros.wire import read_fixed

    base = get_typestore(Stores.ROS1_NOETIC if kind == "rosbag1" else Stores.ROS2_HUMBLE)
    ts = get_typestore(Stores.EMPTY)
    ts.register({k: v for k, v in base.fielddefs.items() if k != "geometry_msgs/msg/PoseStamped"})
    ts.register(get_types_from_msg("std_msgs/Header header\ngeometry_msgs/Pose pose\n"
                                   "float64 quality", "geometry_msgs/msg/PoseStamped"))
    ns, R, p = _drone(5.0)
    q = _wxyz(R)
    T = ts.types
    msgs = []
    for i, s in enumerate(ns.tolist()):
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=p[i, 0], y=p[i, 1], z=p[i, 2]),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q[i, 1], y=q[i, 2], z=q[i, 3],
                                                          w=q[i, 0]))
        msgs.append((s, "/pose", T["geometry_msgs/msg/PoseStamped"](
            header=recordings._header(ts, s), pose=pose, quality=0.5)))
    bag = recordings._write(tmp_path / name, kind, ts, msgs, 0)
    with open_bag(bag) as b:
        _, raws = b.raw("/pose")
        ty = b.topics["/pose"]
        assert read_fixed(raws, ty, b.ros1, b.deserialiser(ty)) is None
    with open_bag(bag) as b:
        got = read_bag_mocap(b, RecordingOptions(), [])
    assert np.array_equal(got.stamps_ns(), ns)
    assert np.array_equal(got.position, p) and np.array_equal(got.quat_wxyz, q)


# --- diagnose through the CLI on a bag and on a ULog ------------------------------------------

def _diagnose(path: Path, out: Path) -> dict:
    code = main(["diagnose", "--imu", str(path), "--mocap", str(path), "--start-model",
                 "base+time_offset", "--candidates", "accel_delay+gyro_scale_misalignment",
                 "--max-steps", "1", "--out", str(out), "-q"])
    assert code == 0
    return yaml.safe_load(out.read_text())


@pytest.mark.slow
def test_diagnose_on_a_bag_and_on_a_ulog(tmp_path) -> None:
    from mocap_calib.io.formats.euroc import write_mav0
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=5, duration=40.0, effects={"time_offset": [0.004]}))
    root = write_mav0(tmp_path / "s", sim.imu, sim.mocap)
    imu, mocap, _ = load_inputs(None, None, root)
    bag = write_bag(tmp_path / "s.mcap", "bare_mcap", imu, mocap)
    # The ULog: microsecond stamps, mocap in NED (z-up world by the reader).
    us = (imu.stamps_ns() // 1000) * 1000
    imu_us = ImuSamples((us - us[0]) * 1e-9, imu.gyro, imu.accel, int(us[0]))
    q_ne = _wxyz(Rotation.from_matrix([[0, 1, 0], [1, 0, 0], [0, 0, -1]]))
    ned_q = _wxyz(_R(q_ne) * _R(mocap.quat_wxyz))
    ned_p = mocap.position[:, [1, 0, 2]] * [1, 1, -1]
    ms = (mocap.stamps_ns() // 1000) * 1000
    ned = MocapPoses((ms - ms[0]) * 1e-9, ned_q, ned_p, int(ms[0]))
    ulg = write_ulog(tmp_path / "s.ulg", imu_us, ned)
    for path, out in ((bag, tmp_path / "bag.yaml"), (ulg, tmp_path / "ulg.yaml")):
        rep = _diagnose(path, out)
        assert rep["verdict"] == "none", path  # the simulator added nothing else
        cal = rep["final_calibration"]
        assert abs(cal["time_offset"] - 0.004) < 4 * cal["sigma"]["time_offset"], path
