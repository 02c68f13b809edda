"""`mocap-calib groundtruth` against the simulator's true IMU trajectory, scored with evo.

The session is calibrated by `mocap-calib calibrate` first (not given the truth); the ground
truth is then read back with evo's own EuRoC/TUM readers and compared by evo's APE with the
simulator's true IMU pose (in the true gravity-aligned world, on the IMU clock).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.groundtruth.smoother import (
    GroundTruthCalibration,
    GroundTruthOptions,
    ground_truth,
)
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.io.formats.euroc import write_mav0
from mocap_calib.sim.flight import SimConfig, simulate_flight

sys.path.insert(0, str(Path(__file__).parent))
from simtruth import Truth, true_trajectory  # noqa: E402

evo_metrics = pytest.importorskip("evo.core.metrics")
from evo.core import sync  # noqa: E402
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402
from evo.tools import file_interface  # noqa: E402

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

CFG = SimConfig(seed=3, duration=60.0, effects={"time_offset": [0.006], "mocap_dropouts": [4]})


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    sim = simulate_flight(CFG)
    truth = true_trajectory(CFG, sim)
    folder = tmp_path_factory.mktemp("gt")
    root = write_mav0(folder / "s", sim.imu, sim.mocap)
    calib = folder / "calib.yaml"
    assert main(["calibrate", str(root), "--out", str(calib), "-q"]) == 0
    return sim, truth, root, calib, folder


def _reference(sim, truth: Truth, stamps_s: np.ndarray) -> PoseTrajectory3D:
    """The true IMU trajectory at IMU-clock stamps, in the true gravity-aligned world."""
    u = stamps_s - sim.imu.time_origin_ns * 1e-9
    R_WI, p_WI = truth.imu_pose(u + truth.t_d)
    R_GW = so3.rotation_between(np.asarray(sim.truth["gravity_in_mocap"]), [0.0, 0.0, -1.0])
    return PoseTrajectory3D(p_WI @ R_GW.T, so3.rotmat_to_quat(R_GW @ R_WI), stamps_s)


def _ape(ref: PoseTrajectory3D, est: PoseTrajectory3D, relation) -> float:
    ref, est = sync.associate_trajectories(ref, est, max_diff=1e-4)
    ape = evo_metrics.APE(relation)
    ape.process_data((ref, est))
    return ape.get_statistic(evo_metrics.StatisticsType.rmse)


def test_groundtruth_matches_simulator_truth_in_evo(calibrated, capsys) -> None:
    sim, truth, root, calib, folder = calibrated
    out = folder / "gt.csv"
    assert main(["groundtruth", "--imu", str(root / "imu0/data.csv"), "--mocap",
                 str(root / "vicon0/data.csv"), "--calibration", str(calib), "--out", str(out),
                 "-q"]) == 0
    assert "wrote" in capsys.readouterr().out
    est = file_interface.read_euroc_csv_trajectory(str(out))
    ref = _reference(sim, truth, est.timestamps)
    t_rmse = _ape(ref, est, evo_metrics.PoseRelation.translation_part)
    r_rmse = _ape(ref, est, evo_metrics.PoseRelation.rotation_angle_deg)
    print(f"APE translation RMSE {1e3 * t_rmse:.3f} mm, rotation RMSE {r_rmse:.4f} deg")
    assert t_rmse < 1e-3 and r_rmse < 0.05
    # The sidecar says how it was made: 4 mocap dropouts, each bridged by the IMU.
    side = yaml.safe_load((folder / "gt.yaml").read_text())
    assert side["kind"] == "groundtruth_report" and side["format"] == "euroc"
    assert len(side["mocap_gaps"]) == 4 and all(g["bridged"] for g in side["mocap_gaps"])
    assert side["samples_written"] == len(est.timestamps)
    # EuRoC layout: velocity and biases, against the truth.
    data = np.loadtxt(out, delimiter=",", comments="#")
    assert data.shape[1] == 17
    u = (data[:, 0].astype(np.int64) - sim.imu.time_origin_ns) * 1e-9
    v_true = truth.traj.velocity(u + truth.t_d) @ so3.rotation_between(
        np.asarray(sim.truth["gravity_in_mocap"]), [0.0, 0.0, -1.0]).T
    assert np.sqrt(np.mean(np.sum((data[:, 8:11] - v_true) ** 2, axis=1))) < 5e-3
    i = np.round(u * 200.0).astype(int)
    assert np.max(np.abs(data[:, 11:14] - sim.gyro_bias_true[i])) < 3e-4
    assert np.max(np.abs(data[:, 14:17] - sim.accel_bias_true[i])) < 2e-2


def test_tum_output_at_a_given_rate(calibrated) -> None:
    sim, truth, root, calib, folder = calibrated
    out = folder / "gt_tum.txt"
    assert main(["groundtruth", str(root), "--calibration", str(calib), "--out", str(out),
                 "--format", "tum", "--rate", "50", "-q"]) == 0
    est = file_interface.read_tum_trajectory_file(str(out))
    u = est.timestamps - sim.imu.time_origin_ns * 1e-9
    np.testing.assert_allclose(np.diff(u), 0.02, atol=1e-6)
    ref = _reference(sim, truth, est.timestamps)
    assert _ape(ref, est, evo_metrics.PoseRelation.translation_part) < 1e-3
    assert _ape(ref, est, evo_metrics.PoseRelation.rotation_angle_deg) < 0.05


def test_long_gap_is_left_out_and_reported(calibrated) -> None:
    sim, truth, *_ = calibrated
    keep = ~((sim.mocap.t > 20.0) & (sim.mocap.t < 26.0))
    t = sim.truth
    cal = GroundTruthCalibration(truth.R_MI, truth.p_MI, np.asarray(t["gravity_in_mocap"]),
                                 9.81, t["time_offset"], np.asarray(t["gyro_bias"]),
                                 np.asarray(t["accel_bias"]))
    gt = ground_truth(sim.imu, sim.mocap.select(keep), cal, NoiseModel(), GroundTruthOptions())
    long = [g for g in gt.report["mocap_gaps"] if g["length_s"] > 5.0]
    assert len(long) == 1 and not long[0]["bridged"]
    spans = gt.report["spans_left_out_s"]
    assert any(a > 20.0 and b < 26.0 and b - a > 3.0 for a, b in spans), spans
    u = (gt.t_ns - sim.imu.time_origin_ns) * 1e-9
    assert not np.any((u > 22.0) & (u < 24.0))  # the middle of the gap is not written
    assert gt.report["samples_left_out"] > 0


def test_bad_groundtruth_input(calibrated, tmp_path, capsys) -> None:
    sim, _, root, calib, _ = calibrated
    other = yaml.safe_load(calib.read_text())
    other["time_offset"] = 500.0
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump(other))
    for args, word in (([str(root), "--calibration", str(wrong)], "overlap"),
                       ([str(root), "--calibration", str(tmp_path / "none.yaml")], "not found"),
                       ([str(root), "--calibration", str(calib), "--format", "kitti"], "tum")):
        code = main(["groundtruth", *args, "--out", str(tmp_path / "g.csv"), "-q"])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert word in err and "Traceback" not in err
