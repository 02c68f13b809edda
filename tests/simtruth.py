"""The simulator's true trajectory, for tests that need noise-free truth between samples.

``simulate_flight`` draws the trajectory first from its seeded generator, so drawing it again
from the same seed gives the same functions. :func:`true_trajectory` checks that against the
simulated mocap (every pose within 5 mm and 0.5 deg), so a change in the simulator's draw order
fails loudly here instead of silently weakening the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.sim.flight import SimConfig, SimulatedSession
from mocap_calib.sim.trajectory import Trajectory, random_trajectory


@dataclass
class Truth:
    """Noise-free truth of a simulated session; times are seconds since the stream origins
    (equal for the IMU and mocap in the default configuration)."""

    traj: Trajectory
    R_MI: np.ndarray
    p_MI: np.ndarray
    g_W: np.ndarray  # gravity vector (m/s^2)
    t_d: float

    def imu_pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R_WI``, ``p_WI`` at mocap-clock times ``s``."""
        return self.traj.rotation(s), self.traj.position(s)

    def marker_pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R_WM``, ``p_WM`` at mocap-clock times ``s`` (the noise-free mocap)."""
        R_WI, p_WI = self.imu_pose(s)
        R_WM = R_WI @ self.R_MI.T
        return R_WM, p_WI - R_WM @ self.p_MI

    def kinematics(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True angular rate ``w_I`` and specific force ``f_I`` at mocap-clock times ``s``."""
        R_WI = self.traj.rotation(s)
        f = np.einsum("nji,nj->ni", R_WI, self.traj.acceleration(s) - self.g_W)
        return self.traj.angular_velocity_body(s), f


def true_trajectory(cfg: SimConfig, sim: SimulatedSession) -> Truth:
    assert cfg.imu_time_origin_ns == cfg.mocap_time_origin_ns
    traj = random_trajectory(np.random.default_rng(cfg.seed), aggressiveness=cfg.aggressiveness)
    t = sim.truth
    truth = Truth(traj, so3.quat_to_rotmat(np.asarray(t["T_marker_imu"]["rotation_wxyz"])),
                  np.asarray(t["T_marker_imu"]["translation"]),
                  t["gravity_magnitude"] * np.asarray(t["gravity_in_mocap"]), t["time_offset"])
    R_WM, p_WM = truth.marker_pose(sim.mocap.t)
    assert np.max(np.linalg.norm(p_WM - sim.mocap.position, axis=1)) < 5e-3
    assert np.max(so3.angle_deg(np.einsum("nji,njk->nik", R_WM, sim.mocap.rotation))) < 0.5
    return truth


def z_scores(res, truth: dict) -> dict[str, np.ndarray]:
    """Per-axis error / reported sigma of a calibration against the simulator's truth file
    (computed here, not by the code under test)."""
    import gtsam

    T = truth["T_marker_imu"]
    R_true = so3.quat_to_rotmat(np.array(T["rotation_wxyz"]))
    d_g = np.asarray(gtsam.Unit3(res.gravity_in_mocap).localCoordinates(
        gtsam.Unit3(np.array(truth["gravity_in_mocap"]))))
    return {
        "R_MI": so3.log(R_true.T @ res.R_marker_imu) / res.sigma_rotation,
        "p_MI": (res.translation - np.array(T["translation"])) / res.sigma_translation,
        "gyro_bias": (res.gyro_bias - np.array(truth["gyro_bias"])) / res.sigma_gyro_bias,
        "accel_bias": (res.accel_bias - np.array(truth["accel_bias"])) / res.sigma_accel_bias,
        "gravity": -d_g / res.sigma_gravity,
        "time_offset": np.array([(res.time_offset - truth["time_offset"])
                                 / res.sigma_time_offset]),
    }
