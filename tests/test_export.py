"""Exports round-trip: each file, read back with its tool's own convention, reproduces our
model's predictions on a simulated session.

The calibration exported is the simulator's truth (a result file of the same keys), with a
clock offset and every IMU intrinsic effect injected, so each target's frames, matrices and
time-offset sign are exercised: a sign or transpose error shifts the predictions by far more
than the 1e-9 tolerance. "Our model's predictions" follow docs/conventions.md:
``w_m = M_g w + G f + b_g``, ``a_m = M_a f + b_a`` at mocap time ``t + t_d`` for an IMU sample
stamped ``t``, and the mocap measures ``T_WM = T_WI T_MI^-1``. They are also checked against
the simulated samples themselves (to the noise level), so the reference is not our code.
Kalibr's file is read as Kalibr reads it (``yaml.safe_load`` and its ``ImuParameters`` checks);
OpenVINS', VINS' and ORB-SLAM3's with OpenCV's ``FileStorage``, as those tools do.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model import so3
from mocap_calib.io.yaml_io import save_yaml
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.workflows.export import export_to_file

sys.path.insert(0, str(Path(__file__).parent))
from simtruth import true_trajectory  # noqa: E402

cv2 = pytest.importorskip("cv2")

CFG = SimConfig(seed=31, duration=30.0, effects={
    "time_offset": [0.006], "gyro_scale_misalignment": [0.01],
    "accel_scale_misalignment": [0.01], "gyro_g_sensitivity": [1e-3]})


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    sim = simulate_flight(CFG)
    truth = true_trajectory(CFG, sim)
    folder = tmp_path_factory.mktemp("export")
    calib = save_yaml(folder / "calib.yaml", sim.truth)
    noise = save_yaml(folder / "noise.yaml", {"gyroscope_noise_density": 1.6968e-04,
                                             "gyroscope_random_walk": 1.9393e-05,
                                             "accelerometer_noise_density": 2.0e-3,
                                             "accelerometer_random_walk": 3.0e-3})
    return sim, truth, calib, noise, folder


def _export(session, target: str) -> Path:
    sim, _, calib, noise, folder = session
    _, path = export_to_file(calib, target, folder / f"out_{target}", noise, imu_rate_hz=200.0)
    return path


def _ours(sim, truth):
    """Our model's noise-free IMU predictions at the IMU stamps, and its parameters."""
    e = sim.truth["effects"]
    M_g = np.asarray(e["gyro_scale_misalignment"]["gyro_matrix"])
    M_a = np.asarray(e["accel_scale_misalignment"]["accel_matrix"])
    G = np.asarray(e["gyro_g_sensitivity"]["g_sensitivity"])
    b_g, b_a = np.asarray(sim.truth["gyro_bias"]), np.asarray(sim.truth["accel_bias"])
    t = sim.imu.t
    w, f = truth.kinematics(t + truth.t_d)
    return w @ M_g.T + f @ G.T + b_g, f @ M_a.T + b_a, (M_g, M_a, G, b_g, b_a)


def _check_against_samples(sim, gyro: np.ndarray, accel: np.ndarray) -> None:
    """The predictions match the simulated samples to the noise level (white noise plus the
    bias random walk around its mean)."""
    rg = sim.imu.gyro - gyro - (sim.gyro_bias_true - sim.gyro_bias_true.mean(axis=0))
    ra = sim.imu.accel - accel - (sim.accel_bias_true - sim.accel_bias_true.mean(axis=0))
    assert np.std(rg) < 1.2 * 1.6968e-04 * math.sqrt(200.0)
    assert np.std(ra) < 1.2 * 2.0e-3 * math.sqrt(200.0)


class KalibrImuParameters:
    """The accessors of Kalibr's ``kalibr_common.ConfigReader.ImuParameters`` (the file is
    read with ``yaml.safe_load``; every getter checks its values as Kalibr's do)."""

    def __init__(self, path: Path) -> None:
        with open(path) as f:
            self.data = yaml.safe_load(f)

    def getRosTopic(self) -> str:  # noqa: N802 (Kalibr's names)
        assert isinstance(self.data["rostopic"], str)
        return self.data["rostopic"]

    def getUpdateRate(self) -> float:  # noqa: N802
        assert self.data["update_rate"] > 0.0
        return self.data["update_rate"]

    def getAccelerometerStatistics(self):  # noqa: N802
        nd, rw = self.data["accelerometer_noise_density"], self.data["accelerometer_random_walk"]
        assert nd > 0.0 and rw > 0.0
        return nd / math.sqrt(1.0 / self.getUpdateRate()), rw, nd

    def getGyroStatistics(self):  # noqa: N802
        nd, rw = self.data["gyroscope_noise_density"], self.data["gyroscope_random_walk"]
        assert nd > 0.0 and rw > 0.0
        return nd / math.sqrt(1.0 / self.getUpdateRate()), rw, nd


def test_kalibr_round_trip(session) -> None:
    sim, truth, *_ = session
    path = _export(session, "kalibr")
    p = KalibrImuParameters(path)
    assert p.getRosTopic() == "/imu0" and p.getUpdateRate() == 200.0
    assert p.getGyroStatistics()[2] == 1.6968e-04 and p.getAccelerometerStatistics()[1] == 3e-3
    d = p.data
    assert d["model"] == "scale-misalignment"
    assert np.array_equal(np.asarray(d["T_i_b"]), np.eye(4))
    M, A, C = (np.asarray(d["gyroscopes"][k]) for k in ("M", "A", "C_gyro_i"))
    M_acc = np.asarray(d["accelerometers"]["M"])
    # Kalibr's free entries: lower-triangular M (gyro and accel), C a rotation.
    assert np.all(np.triu(M, 1) == 0) and np.all(np.triu(M_acc, 1) == 0)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(C) > 0
    # IccScaledMisalignedImu: tk = t_imu + time_offset on the reference (mocap) clock;
    # w = M C w_b + A C a_b + b, a = M_acc a_b + b (reference IMU: C_i_b = I, r_b = 0).
    gyro, accel, (_, _, _, b_g, b_a) = _ours(sim, truth)
    w, f = truth.kinematics(sim.imu.t + d["time_offset"])
    np.testing.assert_allclose(w @ (M @ C).T + f @ (A @ C).T + b_g, gyro, rtol=0, atol=1e-9)
    np.testing.assert_allclose(f @ M_acc.T + b_a, accel, rtol=0, atol=1e-9)
    _check_against_samples(sim, gyro, accel)


def _cv_matrix(node) -> np.ndarray:
    """Read a list-of-rows node element by element, as OpenVINS' YamlParser does."""
    return np.array([[node.at(r).at(c).real() for c in range(node.at(r).size())]
                     for r in range(node.size())])


def test_openvins_round_trip(session) -> None:
    sim, truth, *_ = session
    path = _export(session, "openvins")
    assert path.read_text().startswith("%YAML:1.0")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    imu0 = fs.getNode("imu0")
    assert not imu0.empty()
    Tw, R_gyro, Ta, R_acc, Tg = (_cv_matrix(imu0.getNode(k)) for k in
                                 ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC", "Tg"))
    assert _cv_matrix(imu0.getNode("T_i_b")).shape == (4, 4)
    assert imu0.getNode("gyroscope_noise_density").real() == 1.6968e-04
    assert imu0.getNode("model").string() == "kalibr"
    # OpenVINS' kalibr model keeps the lower triangle of Dw = Tw^-1 and Da = Ta^-1.
    assert np.all(np.abs(np.triu(np.linalg.inv(Tw), 1)) < 1e-15)
    assert np.all(np.abs(np.triu(np.linalg.inv(Ta), 1)) < 1e-15)
    # Propagator: a = R_ACCtoIMU Da (a_m - b_a); w = R_GYROtoIMU Dw (w_m - b_g - Tg a).
    gyro, accel, (_, _, _, b_g, b_a) = _ours(sim, truth)
    a = (accel - b_a) @ (R_acc.T @ np.linalg.inv(Ta)).T
    w = (gyro - b_g - a @ Tg.T) @ (R_gyro.T @ np.linalg.inv(Tw)).T
    w_true, f_true = truth.kinematics(sim.imu.t + imu0.getNode("time_offset").real())
    np.testing.assert_allclose(a, f_true, rtol=0, atol=1e-9)
    np.testing.assert_allclose(w, w_true, rtol=0, atol=1e-9)


def test_vins_round_trip(session) -> None:
    sim, truth, *_ = session
    fs = cv2.FileStorage(str(_export(session, "vins")), cv2.FILE_STORAGE_READ)
    assert fs.getNode("acc_n").real() == 2.0e-3 and fs.getNode("gyr_w").real() == 1.9393e-05
    assert fs.getNode("g_norm").real() == pytest.approx(sim.truth["gravity_magnitude"])
    td = fs.getNode("td").real()
    # VINS: read image (here: mocap) stamp + td = IMU clock. The IMU pose at IMU time s + td
    # is the true pose at mocap time s + td + t_d; composed with T_MI^-1 it must give our
    # model's mocap prediction at stamp s.
    s = sim.mocap.t
    R_WI, p_WI = truth.imu_pose(s + td + truth.t_d)
    R_WM, p_WM = truth.marker_pose(s)
    np.testing.assert_allclose(R_WI @ truth.R_MI.T, R_WM, atol=1e-12)
    np.testing.assert_allclose(p_WI - R_WI @ truth.R_MI.T @ truth.p_MI, p_WM, atol=1e-12)
    assert np.max(np.linalg.norm(p_WM - sim.mocap.position, axis=1)) < 3e-3


def test_orbslam3_round_trip(session) -> None:
    sim, truth, *_ = session
    fs = cv2.FileStorage(str(_export(session, "orbslam3")), cv2.FILE_STORAGE_READ)
    nodes = {k: fs.getNode(f"IMU.{k}") for k in ("NoiseGyro", "NoiseAcc", "GyroWalk", "AccWalk",
                                                 "Frequency")}
    assert all(n.isReal() for n in nodes.values())  # ORB-SLAM3 aborts on non-reals
    # ORB-SLAM3 (Settings/Tracking): per-sample sigma = noise density * sqrt(frequency).
    sf = math.sqrt(nodes["Frequency"].real())
    gyro, accel, _ = _ours(sim, truth)
    # The simulated white noise: first differences of the residual remove the bias walk.
    for meas, pred, key in ((sim.imu.gyro, gyro, "NoiseGyro"), (sim.imu.accel, accel,
                                                                  "NoiseAcc")):
        sigma = np.std(np.diff(meas - pred, axis=0)) / math.sqrt(2.0)
        assert nodes[key].real() * sf == pytest.approx(sigma, rel=0.03)


def test_basalt_round_trip(session) -> None:
    sim, truth, *_ = session
    d = json.loads(_export(session, "basalt").read_text())["value0"]

    def se3(x) -> tuple[np.ndarray, np.ndarray]:
        R = so3.quat_to_rotmat(np.array([x["qw"], x["qx"], x["qy"], x["qz"]]))
        return R, np.array([x["px"], x["py"], x["pz"]])

    R_mw, p_mw = se3(d["T_mocap_world"])
    R_im, p_im = se3(d["T_imu_marker"])
    # Basalt's world is gravity-aligned (z up): its -z is the mocap's gravity direction.
    np.testing.assert_allclose(R_mw @ [0.0, 0.0, -1.0], sim.truth["gravity_in_mocap"],
                               atol=1e-12)
    # spline_linearize.h: t_imu_ns = mocap stamp + mocap_time_offset_ns;
    # T_moc_mark = T_moc_w T_w_i(t) T_i_mark.
    s = sim.mocap.t
    u = s + d["mocap_time_offset_ns"] * 1e-9  # IMU clock
    R_WI, p_WI = truth.imu_pose(u + truth.t_d)
    R_wi, p_wi = R_mw.T @ R_WI, (p_WI - p_mw) @ R_mw  # the IMU in Basalt's world
    R_pred = R_mw @ R_wi @ R_im
    p_pred = (np.einsum("ij,njk,k->ni", R_mw, R_wi, p_im) + p_wi @ R_mw.T + p_mw)
    R_WM, p_WM = truth.marker_pose(s)
    np.testing.assert_allclose(R_pred, R_WM, atol=1e-9)
    np.testing.assert_allclose(p_pred, p_WM, atol=1e-9)


def test_px4_round_trip(session) -> None:
    sim, truth, *_ = session
    params = {}
    for line in _export(session, "px4").read_text().splitlines():
        if line and not line.startswith("#"):
            _, _, name, value, kind = line.split("\t")
            params[name] = float(value)
            assert kind == "9"  # MAV_PARAM_TYPE_REAL32
    # EKF2 (estimator_interface.cpp): a vision sample is valid at stamp - EKF2_EV_DELAY on the
    # autopilot (IMU) clock; EKF2_EV_POS is the sensor's position in the FRD body frame.
    s = sim.mocap.t
    u = s - params["EKF2_EV_DELAY"] * 1e-3
    R_WI, p_WI = truth.imu_pose(u + truth.t_d)
    ev = np.array([params[f"EKF2_EV_POS_{a}"] for a in "XYZ"])
    _, p_WM = truth.marker_pose(s)
    np.testing.assert_allclose(p_WI + R_WI @ ev, p_WM, atol=2e-6)  # params carry 6 decimals


def test_gyro_decomposition_reproduces_our_matrix(session) -> None:
    from mocap_calib.export.intrinsics import lower_times_rotation

    rng = np.random.default_rng(0)
    for _ in range(20):
        m = np.eye(3) + rng.normal(0, 0.05, (3, 3))
        L, C = lower_times_rotation(m)
        np.testing.assert_allclose(L @ C, m, atol=1e-14)
        assert np.all(np.triu(L, 1) == 0) and np.all(np.diag(L) > 0)


def test_export_cli_and_bad_input(session, tmp_path, capsys) -> None:
    _, _, calib, noise, _ = session
    out = tmp_path / "imu.yaml"
    assert main(["export", str(calib), "--to", "kalibr", "--out", str(out), "--noise",
                 str(noise), "--imu-rate", "200"]) == 0
    assert "wrote" in capsys.readouterr().out and out.is_file()
    for args, words in ((["--to", "rovio"], ["rovio", "kalibr"]),
                        (["--to", "kalibr"], ["--imu-rate"])):
        code = main(["export", str(calib), *args, "--out", str(tmp_path / "x")])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert all(w in err for w in words), err
