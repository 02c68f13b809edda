"""The flight simulator against the conventions, checked independently of the simulator's own
arithmetic: finite differences of the trajectory and of the written mocap poses, the measurement
model written out here from docs/conventions.md, statistics of the injected noise, and the
mocap faults seen in the poses themselves."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, SimulatedSession, parse_effect, simulate_flight
from mocap_calib.sim.trajectory import random_trajectory

ORIGIN_NS = 1_600_000_000_000_000_000

# White noise and mocap noise ~0; the bias random walks keep their EuRoC densities so the
# per-sample biases really vary.
QUIET = NoiseModel(gyroscope_noise_density=1e-13, gyroscope_random_walk=1.9393e-05,
                   accelerometer_noise_density=1e-13, accelerometer_random_walk=3.0e-3,
                   mocap_position_sigma=1e-13, mocap_rotation_sigma=1e-13)

# Explicit effect values (matrices row-major, 9 values; M_a - I lower-triangular).
GYRO_MATRIX_DELTA = [0.01, -0.02, 0.005, 0.015, -0.01, 0.02, -0.005, 0.01, 0.03]
ACCEL_MATRIX_DELTA = [0.02, 0.0, 0.0, -0.01, 0.015, 0.0, 0.005, 0.01, -0.02]
G_SENS = [1e-3, -2e-3, 5e-4, 0.0, 1e-3, -1e-3, 2e-3, 5e-4, -5e-4]
GYRO_DRIFT = [2e-4, -3e-4, 1e-4]
ACCEL_DRIFT = [3e-3, 2e-3, -4e-3]


# --- independent helpers ---------------------------------------------------------------------

def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """Hamilton quaternion [w, x, y, z] -> rotation matrix (written out, not the project's)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def vee_of_skew_part(A: np.ndarray) -> np.ndarray:
    return 0.5 * np.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0],
                           A[..., 1, 0] - A[..., 0, 1]], axis=-1)


def body_rate_fd(R: Callable[[np.ndarray], np.ndarray], t: np.ndarray, h: float) -> np.ndarray:
    """``w`` with ``[w]x = R^T dR/dt`` (angular velocity in the moving frame), central diff."""
    Rdot = (R(t + h) - R(t - h)) / (2 * h)
    return vee_of_skew_part(np.swapaxes(R(t), -1, -2) @ Rdot)


def expected_imu(sim: SimulatedSession, effects: dict[str, list[float] | None],
                 time_offset: float, gravity_magnitude: float,
                 use_truth_effects: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro and accel by the conventions' model from finite differences of the mocap poses.

    ``T_WI = T_WM T_MI`` (T_MI from truth.yaml); the IMU sample stamped ``t`` is compared with
    the mocap-derived signals at mocap time ``t + t_d``. Needs mocap rate == IMU rate so that
    ``t + t_d`` falls on a mocap sample (``t_d`` a multiple of the period).

    Returns:
        Indices of the IMU samples compared, expected gyro, expected accel.
    """
    truth = sim.truth
    R_MI = quat_wxyz_to_matrix(truth["T_marker_imu"]["rotation_wxyz"])
    p_MI = np.asarray(truth["T_marker_imu"]["translation"])
    R_WM = quat_wxyz_to_matrix(sim.mocap.quat_wxyz)
    R_WI = R_WM @ R_MI
    p_WI = sim.mocap.position + R_WM @ p_MI
    ns_m = sim.mocap.stamps_ns()
    ns_i = sim.imu.stamps_ns()
    h_ns = int(np.median(np.diff(ns_m)))
    h = h_ns * 1e-9
    want = ns_i + int(round(time_offset * 1e9))
    j = np.searchsorted(ns_m, want)
    ok = (j >= 1) & (j < len(ns_m) - 1)
    ok[ok] &= (ns_m[j[ok]] == want[ok]) & (ns_m[j[ok] - 1] == want[ok] - h_ns) \
        & (ns_m[j[ok] + 1] == want[ok] + h_ns)
    idx = np.flatnonzero(ok)
    j = j[ok]
    assert len(idx) > 0.9 * len(ns_i) - abs(time_offset) / h - 5
    w = vee_of_skew_part(np.swapaxes(R_WI[j], 1, 2) @ (R_WI[j + 1] - R_WI[j - 1]) / (2 * h))
    a_W = (p_WI[j + 1] - 2 * p_WI[j] + p_WI[j - 1]) / h**2
    g_W = gravity_magnitude * np.asarray(truth["gravity_in_mocap"])
    f = np.einsum("nji,nj->ni", R_WI[j], a_W - g_W)

    if use_truth_effects:
        eff = truth["effects"]
        M_g = np.asarray(eff.get("gyro_scale_misalignment", {}).get("gyro_matrix", np.eye(3)))
        M_a = np.asarray(eff.get("accel_scale_misalignment", {}).get("accel_matrix", np.eye(3)))
        G = np.asarray(eff.get("gyro_g_sensitivity", {}).get("g_sensitivity", np.zeros((3, 3))))
    else:
        M_g = np.eye(3) + (np.reshape(effects["gyro_scale_misalignment"], (3, 3))
                           if "gyro_scale_misalignment" in effects else 0.0)
        M_a = np.eye(3) + (np.reshape(effects["accel_scale_misalignment"], (3, 3))
                           if "accel_scale_misalignment" in effects else 0.0)
        G = (np.reshape(effects["gyro_g_sensitivity"], (3, 3))
             if "gyro_g_sensitivity" in effects else np.zeros((3, 3)))
    gyro = w @ M_g.T + f @ G.T + sim.gyro_bias_true[idx]
    accel = f @ M_a.T + sim.accel_bias_true[idx]
    return idx, gyro, accel


def fast_config(**kw: object) -> SimConfig:
    base: dict[str, object] = dict(seed=3, duration=10.0, imu_rate=1000.0, mocap_rate=1000.0,
                                   noise=QUIET)
    base.update(kw)
    return SimConfig(**base)  # type: ignore[arg-type]


# --- the trajectory's analytic derivatives ---------------------------------------------------

@pytest.mark.parametrize("seed,aggressiveness", [(0, 1.0), (1, 1.0), (2, 2.0), (3, 0.5)])
def test_trajectory_derivatives_match_finite_differences(seed: int, aggressiveness: float) -> None:
    traj = random_trajectory(np.random.default_rng(seed), aggressiveness=aggressiveness)
    t = np.linspace(0.0, 120.0, 997)
    R = traj.rotation(t)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)

    w_fd = body_rate_fd(traj.rotation, t, 1e-5)
    np.testing.assert_allclose(traj.angular_velocity_body(t), w_fd, rtol=1e-8, atol=1e-8)
    # The world-frame alternative would differ: make sure the test distinguishes frames.
    w_world = np.einsum("nij,nj->ni", R, w_fd)
    assert np.abs(w_world - w_fd).max() > 0.1

    h = 1e-5
    v_fd = (traj.position(t + h) - traj.position(t - h)) / (2 * h)
    np.testing.assert_allclose(traj.velocity(t), v_fd, rtol=1e-8, atol=1e-8)
    a_fd = (traj.velocity(t + h) - traj.velocity(t - h)) / (2 * h)
    np.testing.assert_allclose(traj.acceleration(t), a_fd, rtol=1e-8, atol=1e-8)
    # Truncation ~ h^2 |p''''| / 12 ~ 1e-5; roundoff of the sine arguments (~1e3 rad) / h^2.
    h2 = 1e-3
    a_fd2 = (traj.position(t + h2) - 2 * traj.position(t) + traj.position(t - h2)) / h2**2
    np.testing.assert_allclose(traj.acceleration(t), a_fd2, rtol=0, atol=1e-4)


def test_trajectory_is_drone_like() -> None:
    """Documented envelope: within +-2 m horizontally, roll/pitch within +-40 deg."""
    traj = random_trajectory(np.random.default_rng(5))
    t = np.linspace(0.0, 300.0, 30001)
    p = traj.position(t)
    assert np.abs(p[:, :2]).max() <= 2.0
    assert np.abs(p[:, 2] - 1.3).max() <= 0.8
    R = traj.rotation(t)
    pitch = -np.arcsin(np.clip(R[:, 2, 0], -1, 1))
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    assert np.degrees(np.abs(pitch)).max() <= 40.0 + 1e-9
    assert np.degrees(np.abs(roll)).max() <= 40.0 + 1e-9


# --- end to end: IMU samples == conventions' model of the written mocap poses ----------------

EFFECT_CASES: dict[str, dict[str, list[float] | None]] = {
    "base": {},
    "time_offset+": {"time_offset": [0.012]},
    "time_offset-": {"time_offset": [-0.007]},
    "gyro_scale_misalignment": {"gyro_scale_misalignment": GYRO_MATRIX_DELTA},
    "accel_scale_misalignment": {"accel_scale_misalignment": ACCEL_MATRIX_DELTA},
    "gyro_g_sensitivity": {"gyro_g_sensitivity": G_SENS},
    "gyro_bias_drift": {"gyro_bias_drift": GYRO_DRIFT},
    "accel_bias_drift": {"accel_bias_drift": ACCEL_DRIFT},
    "gravity_magnitude": {"gravity_magnitude": [9.79]},
    "all": {"time_offset": [0.009], "gyro_scale_misalignment": GYRO_MATRIX_DELTA,
            "accel_scale_misalignment": ACCEL_MATRIX_DELTA, "gyro_g_sensitivity": G_SENS,
            "gyro_bias_drift": GYRO_DRIFT, "accel_bias_drift": ACCEL_DRIFT,
            "gravity_magnitude": [9.83]},
}

GYRO_TOL = 1e-4  # rad/s: finite-difference error at 1 kHz is ~1e-5
ACCEL_TOL = 1e-4  # m/s^2


@pytest.mark.parametrize("case", list(EFFECT_CASES))
def test_imu_samples_follow_measurement_model_of_mocap_poses(case: str) -> None:
    effects = EFFECT_CASES[case]
    sim = simulate_flight(fast_config(effects=effects))
    t_d = effects.get("time_offset", [0.0])[0]
    g = effects.get("gravity_magnitude", [9.81])[0]
    idx, gyro, accel = expected_imu(sim, effects, t_d, g)
    np.testing.assert_allclose(sim.imu.gyro[idx], gyro, rtol=0, atol=GYRO_TOL)
    np.testing.assert_allclose(sim.imu.accel[idx], accel, rtol=0, atol=ACCEL_TOL)

    # The truth file reports what was injected, in the conventions' form.
    truth = sim.truth
    assert truth["time_offset"] == pytest.approx(t_d, abs=1e-15)
    assert truth["gravity_magnitude"] == pytest.approx(g, abs=1e-12)
    eff = truth["effects"]
    assert set(eff) == set(effects)
    if "gyro_scale_misalignment" in effects:
        np.testing.assert_allclose(eff["gyro_scale_misalignment"]["gyro_matrix"],
                                   np.eye(3) + np.reshape(GYRO_MATRIX_DELTA, (3, 3)), atol=1e-15)
    if "accel_scale_misalignment" in effects:
        np.testing.assert_allclose(eff["accel_scale_misalignment"]["accel_matrix"],
                                   np.eye(3) + np.reshape(ACCEL_MATRIX_DELTA, (3, 3)), atol=1e-15)
    if "gyro_g_sensitivity" in effects:
        np.testing.assert_allclose(eff["gyro_g_sensitivity"]["g_sensitivity"],
                                   np.reshape(G_SENS, (3, 3)), atol=1e-15)
    if "gyro_bias_drift" in effects:
        np.testing.assert_allclose(eff["gyro_bias_drift"]["gyro_bias_rate"], GYRO_DRIFT)
    if "accel_bias_drift" in effects:
        np.testing.assert_allclose(eff["accel_bias_drift"]["accel_bias_rate"], ACCEL_DRIFT)
    assert truth["model"].split("+")[0] == "base"
    assert set(truth["model"].split("+")[1:]) == set(effects)


def test_model_check_detects_wrong_time_offset_sign_and_missing_effects() -> None:
    """The comparison above is sensitive: the opposite clock sign, a forgotten effect or the
    assumed gravity give residuals far above the tolerances."""
    effects = EFFECT_CASES["all"]
    sim = simulate_flight(fast_config(effects=effects))
    idx, gyro, accel = expected_imu(sim, effects, -0.009, 9.83)
    assert np.abs(sim.imu.gyro[idx] - gyro).max() > 100 * GYRO_TOL
    idx, gyro, accel = expected_imu(sim, effects, 0.009, 9.81)
    assert np.abs(sim.imu.accel[idx] - accel).max() > 100 * ACCEL_TOL
    reduced = {k: v for k, v in effects.items() if k != "gyro_g_sensitivity"}
    idx, gyro, accel = expected_imu(sim, reduced, 0.009, 9.83)
    assert np.abs(sim.imu.gyro[idx] - gyro).max() > 30 * GYRO_TOL


def test_drawn_effects_match_the_truth_file() -> None:
    """Effects without values draw realistic magnitudes; truth.yaml must report the ones used."""
    effects: dict[str, list[float] | None] = {
        "gyro_scale_misalignment": None, "accel_scale_misalignment": None,
        "gyro_g_sensitivity": None, "gyro_bias_drift": None, "accel_bias_drift": None,
        "gravity_magnitude": None}
    sim = simulate_flight(fast_config(seed=8, effects=effects))
    idx, gyro, accel = expected_imu(sim, effects, 0.0, sim.truth["gravity_magnitude"],
                                    use_truth_effects=True)
    np.testing.assert_allclose(sim.imu.gyro[idx], gyro, rtol=0, atol=GYRO_TOL)
    np.testing.assert_allclose(sim.imu.accel[idx], accel, rtol=0, atol=ACCEL_TOL)
    M_a = np.asarray(sim.truth["effects"]["accel_scale_misalignment"]["accel_matrix"])
    assert np.all(np.triu(M_a, 1) == 0.0), "M_a must be lower-triangular (conventions)"
    M_g = np.asarray(sim.truth["effects"]["gyro_scale_misalignment"]["gyro_matrix"])
    assert 0 < np.abs(M_g - np.eye(3)).max() < 0.05


def test_white_noise_has_the_noise_model_density() -> None:
    """Residual of the IMU samples against the mocap-derived model is the white noise:
    std = density * sqrt(rate) (Kalibr's discretisation)."""
    noise = NoiseModel(mocap_position_sigma=1e-13, mocap_rotation_sigma=1e-13)
    sim = simulate_flight(fast_config(seed=12, noise=noise, duration=12.0))
    idx, gyro, accel = expected_imu(sim, {}, 0.0, 9.81)
    std_g = (sim.imu.gyro[idx] - gyro).std(axis=0)
    std_a = (sim.imu.accel[idx] - accel).std(axis=0)
    np.testing.assert_allclose(std_g, noise.gyroscope_noise_density * np.sqrt(1000.0), rtol=0.05)
    np.testing.assert_allclose(std_a, noise.accelerometer_noise_density * np.sqrt(1000.0),
                               rtol=0.05)


def test_bias_random_walk_has_the_noise_model_density() -> None:
    noise = NoiseModel(gyroscope_random_walk=2e-4, accelerometer_random_walk=5e-3)
    sim = simulate_flight(SimConfig(seed=4, duration=20.0, noise=noise))
    dt = 1.0 / 200.0
    inc_g = np.diff(sim.gyro_bias_true, axis=0)
    inc_a = np.diff(sim.accel_bias_true, axis=0)
    np.testing.assert_allclose(inc_g.std(axis=0), 2e-4 * np.sqrt(dt), rtol=0.06)
    np.testing.assert_allclose(inc_a.std(axis=0), 5e-3 * np.sqrt(dt), rtol=0.06)
    # A random walk has zero-mean increments (no hidden trend without bias_drift): 5 sigma.
    assert np.all(np.abs(inc_g.mean(axis=0)) < 5 * 2e-4 * np.sqrt(dt / len(inc_g)))
    assert np.all(np.abs(inc_a.mean(axis=0)) < 5 * 5e-3 * np.sqrt(dt / len(inc_a)))


def test_mocap_noise_has_the_noise_model_sigmas() -> None:
    """Position: third differences of white noise have variance 20 sigma^2 (the smooth motion
    contributes ~1e-7 m at 1 kHz). Rotation: body-frame increments Log(R_i^T R_i+1) differ
    by n_i+2 - 2 n_i+1 + n_i to first order, variance 6 sigma^2 per axis."""
    noise = NoiseModel(mocap_position_sigma=0.8e-3, mocap_rotation_sigma=np.radians(0.1))
    sim = simulate_flight(fast_config(seed=13, noise=noise))
    d3 = np.diff(sim.mocap.position, n=3, axis=0)
    np.testing.assert_allclose(d3.std(axis=0) / np.sqrt(20.0), 0.8e-3, rtol=0.05)
    R = quat_wxyz_to_matrix(sim.mocap.quat_wxyz)
    inc = Rotation.from_matrix(np.swapaxes(R[:-1], 1, 2) @ R[1:]).as_rotvec()
    d = np.diff(inc, axis=0)
    np.testing.assert_allclose(d.std(axis=0) / np.sqrt(6.0), np.radians(0.1), rtol=0.05)


# --- biases: definition and drift ------------------------------------------------------------

def test_truth_bias_is_mean_of_per_sample_bias() -> None:
    sim = simulate_flight(SimConfig(seed=21, duration=15.0,
                                    effects={"gyro_bias_drift": None, "accel_bias_drift": None}))
    truth = sim.truth
    assert sim.gyro_bias_true.shape == sim.accel_bias_true.shape == (len(sim.imu), 3)
    np.testing.assert_allclose(truth["gyro_bias"], sim.gyro_bias_true.mean(axis=0),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(truth["accel_bias"], sim.accel_bias_true.mean(axis=0),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(truth["simulation"]["gyro_bias_initial"], sim.gyro_bias_true[0])
    np.testing.assert_allclose(truth["simulation"]["accel_bias_initial"], sim.accel_bias_true[0])
    assert "mean" in truth["simulation"]["bias_definition"]
    # The bias really varies over the session (random walk + trend), so "mean" matters.
    assert np.abs(sim.accel_bias_true[-1] - sim.accel_bias_true[0]).max() > 1e-3


def test_bias_drift_is_linear_trend_centred_on_session_middle() -> None:
    """Without random walk the bias is ``b + r (t - t_mid)`` exactly: its mean (the truth
    bias) is its value at the middle sample, and its slope is the injected rate."""
    noise = NoiseModel(gyroscope_random_walk=1e-15, accelerometer_random_walk=1e-15)
    sim = simulate_flight(SimConfig(seed=22, duration=10.0, noise=noise, effects={
        "gyro_bias_drift": GYRO_DRIFT, "accel_bias_drift": ACCEL_DRIFT}))
    t = (sim.imu.stamps_ns() - ORIGIN_NS) * 1e-9
    n = len(t)
    assert n == 2001
    mid = n // 2
    for bias, rate, key in ((sim.gyro_bias_true, GYRO_DRIFT, "gyro_bias"),
                            (sim.accel_bias_true, ACCEL_DRIFT, "accel_bias")):
        np.testing.assert_allclose(bias - bias[0], np.outer(t - t[0], rate), rtol=0, atol=1e-12)
        np.testing.assert_allclose(sim.truth[key], bias[mid], rtol=0, atol=1e-12)
        np.testing.assert_allclose(bias[mid] - bias[0], np.multiply(rate, 5.0), atol=1e-12)


# --- determinism -----------------------------------------------------------------------------

def _arrays(sim: SimulatedSession) -> list[np.ndarray]:
    return [sim.imu.t, sim.imu.gyro, sim.imu.accel, sim.mocap.t, sim.mocap.quat_wxyz,
            sim.mocap.position, sim.gyro_bias_true, sim.accel_bias_true,
            sim.imu.stamps_ns(), sim.mocap.stamps_ns()]


def test_same_seed_same_session_different_seed_different() -> None:
    effects: dict[str, list[float] | None] = {name: None for name in (
        "time_offset", "gyro_scale_misalignment", "accel_scale_misalignment",
        "gyro_g_sensitivity", "gyro_bias_drift", "accel_bias_drift", "gravity_magnitude",
        "mocap_dropouts", "mocap_outliers")}
    cfg = SimConfig(seed=31, duration=8.0, effects=effects)
    a, b = simulate_flight(cfg), simulate_flight(cfg)
    for x, y in zip(_arrays(a), _arrays(b), strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.truth == b.truth
    c = simulate_flight(SimConfig(seed=32, duration=8.0, effects=effects))
    assert not np.array_equal(a.imu.gyro, c.imu.gyro)
    assert not np.array_equal(a.mocap.position[:10], c.mocap.position[:10])
    assert a.truth["T_marker_imu"] != c.truth["T_marker_imu"]
    assert a.truth["gyro_bias"] != c.truth["gyro_bias"]
    assert a.truth["effects"] != c.truth["effects"]


def test_stamps_are_exact_nanosecond_grids() -> None:
    sim = simulate_flight(SimConfig(seed=1, duration=5.0, imu_rate=200.0, mocap_rate=120.0))
    np.testing.assert_array_equal(sim.imu.stamps_ns(),
                                  ORIGIN_NS + np.arange(1001, dtype=np.int64) * 5_000_000)
    k = np.arange(601, dtype=np.int64)
    np.testing.assert_array_equal(sim.mocap.stamps_ns(), ORIGIN_NS + (k * 10**9 + 60) // 120)


# --- mocap faults ----------------------------------------------------------------------------

def test_mocap_dropouts_remove_rows_inside_the_reported_gaps() -> None:
    sim = simulate_flight(SimConfig(seed=41, duration=20.0, noise=QUIET,
                                    effects={"mocap_dropouts": [4]}))
    sim_info = sim.truth["simulation"]
    gaps = sim_info["mocap_gaps_start_length_s"]
    assert len(gaps) == 4
    full = ORIGIN_NS + np.arange(2001, dtype=np.int64) * 10_000_000
    t_full = (full - ORIGIN_NS) * 1e-9
    removed = np.zeros(len(full), dtype=bool)
    for start, length in gaps:
        assert 0.05 * 20.0 <= start <= 0.95 * 20.0
        assert 0.05 <= length <= 1.0
        removed |= (t_full >= start - 1e-9) & (t_full < start + length - 1e-9)
    np.testing.assert_array_equal(sim.mocap.stamps_ns(), full[~removed])
    assert sim_info["mocap_rows_removed"] == int(removed.sum()) > 0
    assert len(sim.imu) == 4001  # the IMU is untouched
    assert sim_info["mocap_outlier_rows"] == []


def _runs(rows: list[int]) -> list[list[int]]:
    runs: list[list[int]] = []
    for r in sorted(set(rows)):
        if runs and r == runs[-1][-1] + 1:
            runs[-1].append(r)
        else:
            runs.append([r])
    return runs


def test_mocap_outliers_displace_exactly_the_reported_rows() -> None:
    count = 6
    sim = simulate_flight(SimConfig(seed=42, duration=20.0, noise=QUIET,
                                    effects={"mocap_outliers": [count]}))
    rows = sim.truth["simulation"]["mocap_outlier_rows"]
    n = len(sim.mocap)
    assert n == 2001 and sim.truth["simulation"]["mocap_rows_removed"] == 0
    assert count <= len(rows) <= 4 * count
    assert all(10 <= r < n for r in rows)
    runs = _runs(rows)
    assert 1 <= len(runs) <= count
    t = sim.mocap.t
    p = sim.mocap.position
    R = quat_wxyz_to_matrix(sim.mocap.quat_wxyz)
    bad = np.zeros(n, dtype=bool)
    bad[rows] = True
    clean = ~bad

    # Listed rows jump away from the smooth path through the clean rows.
    p_spline = CubicSpline(t[clean], p[clean])
    r_spline = RotationSpline(t[clean], Rotation.from_matrix(R[clean]))
    single = [r for r in rows if rows.count(r) == 1]
    for r in rows:
        jump = np.linalg.norm(p[r] - p_spline(t[r]))
        ang = np.degrees(np.linalg.norm(
            (r_spline(t[r]).inv() * Rotation.from_matrix(R[r])).as_rotvec()))
        assert jump > 0.02 and ang > 3.0, (r, jump, ang)
        if r in single:  # one event: 3-10 cm and 5-30 deg, up to interpolation error
            assert 0.03 - 2e-3 <= jump <= 0.10 + 2e-3, (r, jump)
            assert 5.0 - 0.5 <= ang <= 30.0 + 0.5, (r, ang)

    # Rows not listed are untouched: each sits on the midpoint of its clean neighbours.
    i = np.arange(1, n - 1)
    i = i[clean[i - 1] & clean[i] & clean[i + 1]]
    mid_p = 0.5 * (p[i - 1] + p[i + 1])
    assert np.linalg.norm(p[i] - mid_p, axis=1).max() < 2e-3
    half = Rotation.from_rotvec(0.5 * Rotation.from_matrix(
        np.swapaxes(R[i - 1], 1, 2) @ R[i + 1]).as_rotvec())
    mid_R = Rotation.from_matrix(R[i - 1]) * half
    dev = (mid_R.inv() * Rotation.from_matrix(R[i])).magnitude()
    assert np.degrees(dev).max() < 0.5
    # Every clean row next to a run is also clean relative to its other neighbour.
    for run in runs:
        for r in (run[0] - 1, run[-1] + 1):
            assert clean[r]


# --- bad input -------------------------------------------------------------------------------

def test_parse_effect_accepts_canonical_forms() -> None:
    assert parse_effect("time_offset") == ("time_offset", None)
    assert parse_effect("time_offset=0.012") == ("time_offset", [0.012])
    assert parse_effect(" gyro_bias_drift = 1e-5, -2e-5 ,3e-5") == (
        "gyro_bias_drift", [1e-5, -2e-5, 3e-5])
    name, vals = parse_effect("gyro_scale_misalignment=" + ",".join(map(str, GYRO_MATRIX_DELTA)))
    assert name == "gyro_scale_misalignment" and vals == GYRO_MATRIX_DELTA
    assert parse_effect("mocap_dropouts=3") == ("mocap_dropouts", [3.0])


@pytest.mark.parametrize("spec,must_contain", [
    ("bogus", ["bogus", "time_offset", "gyro_scale_misalignment", "mocap_outliers"]),
    ("time_ofset=0.01", ["time_ofset", "time_offset"]),
    ("=0.01", ["unknown effect"]),
    ("time_offset=abc", ["time_offset=abc", "number"]),
    ("time_offset=0.01,", ["number"]),
    ("gyro_bias_drift=1e-5;2e-5;3e-5", ["number"]),
    ("time_offset=nan", ["finite"]),
    ("time_offset=inf", ["finite"]),
    ("gyro_bias_drift=1e-5,nan,2e-5", ["finite"]),
])
def test_parse_effect_rejects_bad_specs(spec: str, must_contain: list[str]) -> None:
    with pytest.raises(InputError) as err:
        parse_effect(spec)
    msg = str(err.value)
    assert "\n" not in msg
    for part in must_contain:
        assert part in msg, (part, msg)


@pytest.mark.parametrize("kw,must_contain", [
    ({"duration": 1.0}, "--duration"),
    ({"duration": 0.0}, "--duration"),
    ({"duration": -5.0}, "--duration"),
    ({"duration": float("nan")}, "--duration"),
    ({"duration": 5 * 3600.0}, "--duration"),
    ({"imu_rate": 0.5}, "--imu-rate"),
    ({"imu_rate": 2e4}, "--imu-rate"),
    ({"imu_rate": float("nan")}, "--imu-rate"),
    ({"mocap_rate": 0.0}, "--mocap-rate"),
    ({"mocap_rate": 400.0}, "--mocap-rate"),
    ({"effects": {"gravity_magnitude": [98.1]}}, "gravity_magnitude"),
    ({"effects": {"gravity_magnitude": [-9.81]}}, "gravity_magnitude"),
])
def test_bad_sim_config_raises_input_error(kw: dict[str, object], must_contain: str) -> None:
    with pytest.raises(InputError, match=must_contain):
        simulate_flight(SimConfig(**{"duration": 5.0, **kw}))  # type: ignore[arg-type]


@pytest.mark.parametrize("spec", ["mocap_outliers=-1", "mocap_dropouts=-2",
                                  "mocap_outliers=100000", "gyro_scale_misalignment=-0.01"])
def test_out_of_range_effect_values_raise_input_error(spec: str) -> None:
    name = spec.split("=")[0]
    with pytest.raises(InputError, match=name):
        name, values = parse_effect(spec)
        simulate_flight(SimConfig(duration=5.0, effects={name: values}))


@pytest.mark.parametrize("spec", ["gyro_scale_misalignment=0.01,0.02",
                                  "gyro_g_sensitivity=1e-3,1e-3,1e-3,1e-3",
                                  "accel_bias_drift=1e-3,2e-3",
                                  "time_offset=0.01,0.02"])
def test_wrong_number_of_effect_values_raises_input_error(spec: str) -> None:
    name = spec.split("=")[0]
    with pytest.raises(InputError, match=name):
        name, values = parse_effect(spec)
        simulate_flight(SimConfig(duration=5.0, effects={name: values}))
