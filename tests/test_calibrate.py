"""Calibration accuracy and honesty against the simulator's truth, and failure modes."""

from __future__ import annotations

import re

import gtsam
import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.prepare.crop import crop_session
from mocap_calib.errors import InputError, ObservabilityError
from mocap_calib.sim.flight import SimConfig, simulate_flight

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

# Accuracy bounds of a default calibration (90 s, a few ms of clock offset).
#: About three times the worst error achieved on these seeds (0.0037 deg, 0.21 mm, 9.3e-5 rad/s,
#: 1.5e-3 m/s^2, 0.0043 deg, 0.013 ms), so that a regression of a few times fails; each is also
#: within the original targets (0.05 deg, 2 mm, 2e-4 rad/s, 5e-3 m/s^2, 0.02 deg, 0.2 ms).
TARGETS = {"rotation_deg": 0.012, "translation_m": 0.65e-3, "gyro_bias": 2e-4,
           "accel_bias": 4.5e-3, "gravity_deg": 0.013, "time_offset_s": 0.04e-3}
MAX_Z = 4.0


def errors_vs_truth(res, truth) -> tuple[dict[str, float], dict[str, float]]:
    """Errors (target units) and |error| / sigma, computed here from the truth file."""
    T = truth["T_marker_imu"]
    R_true = so3.quat_to_rotmat(np.array(T["rotation_wxyz"]))
    R_est = so3.quat_to_rotmat(res.rotation_wxyz)
    d_rot = so3.log(R_true.T @ R_est)  # right perturbation, as sigma.rotation
    d_p = res.translation - np.array(T["translation"])
    d_bg = res.gyro_bias - np.array(truth["gyro_bias"])
    d_ba = res.accel_bias - np.array(truth["accel_bias"])
    g_true = np.array(truth["gravity_in_mocap"])
    u = gtsam.Unit3(res.gravity_in_mocap)
    d_g = np.asarray(u.localCoordinates(gtsam.Unit3(g_true)))
    d_t = res.time_offset - truth["time_offset"]
    err = {"rotation_deg": float(np.degrees(np.linalg.norm(d_rot))),
           "translation_m": float(np.linalg.norm(d_p)),
           "gyro_bias": float(np.abs(d_bg).max()), "accel_bias": float(np.abs(d_ba).max()),
           "gravity_deg": float(np.degrees(np.arccos(np.clip(g_true @ res.gravity_in_mocap,
                                                             -1, 1)))),
           "time_offset_s": abs(d_t)}
    z = {"rotation": np.abs(d_rot / res.sigma_rotation).max(),
         "translation": np.abs(d_p / res.sigma_translation).max(),
         "gyro_bias": np.abs(d_bg / res.sigma_gyro_bias).max(),
         "accel_bias": np.abs(d_ba / res.sigma_accel_bias).max(),
         "gravity": np.abs(d_g / res.sigma_gravity).max(),
         "time_offset": abs(d_t) / res.sigma_time_offset}
    return err, {k: float(v) for k, v in z.items()}


@pytest.mark.parametrize("seed", range(6))
def test_accuracy_and_honest_sigmas(seed: int) -> None:
    t_d = [0.002, 0.004, 0.007, -0.003, 0.005, 0.009][seed]
    sim = simulate_flight(SimConfig(seed=100 + seed, duration=90.0,
                                    effects={"time_offset": [t_d]}))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    err, z = errors_vs_truth(res, sim.truth)
    for k, limit in TARGETS.items():
        assert err[k] < limit, f"{k}: error {err[k]:.3g} >= target {limit}"
    for k, v in z.items():
        assert v < MAX_Z, f"{k}: error is {v:.2f} sigma"
    assert not res.unobservable
    assert res.stages[2].chi2_per_dof == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize("seed", [1, 2])
def test_outliers_and_dropouts(seed: int) -> None:
    sim = simulate_flight(SimConfig(seed=200 + seed, duration=90.0, effects={
        "time_offset": [0.004], "mocap_outliers": [12], "mocap_dropouts": [6]}))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    err, z = errors_vs_truth(res, sim.truth)
    for k, limit in TARGETS.items():
        assert err[k] < limit, f"{k}: error {err[k]:.3g} >= target {limit}"
    for k, v in z.items():
        assert v < MAX_Z, f"{k}: error is {v:.2f} sigma"
    # The marker swaps were found (removed as spikes or down-weighted), sample by sample against
    # the simulator's outlier rows: none missed, and few good samples flagged with them (the
    # spike screen also drops the sample on each side of an event, whose second difference the
    # jump spoils).
    tr = res.diagnostics.trace
    rate = sim.truth["simulation"]["mocap_rate"]

    def rows_of(t: np.ndarray) -> set[int]:
        return set(np.round(np.asarray(t) * rate).astype(int).tolist())

    injected = set(sim.truth["simulation"]["mocap_outlier_rows"]) & rows_of(sim.mocap.t)
    win = tr.windows
    flagged = rows_of(tr.session.removed_tau) | rows_of(win.tau[win.mask & (tr.weights < 0.5)])
    assert injected and not injected - flagged, f"missed rows {sorted(injected - flagged)}"
    assert len(flagged - injected) <= 3 * 12, f"{len(flagged - injected)} good samples flagged"


def test_clocks_from_different_epochs() -> None:
    """IMU stamps from boot time, mocap stamps in Unix time: the raw stamps do not overlap."""
    sim = simulate_flight(SimConfig(seed=31, duration=60.0, effects={"time_offset": [0.0063]},
                                    imu_time_origin_ns=12_345_678_901,
                                    mocap_time_origin_ns=1_700_000_000_000_000_000))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    shift = (1_700_000_000_000_000_000 - 12_345_678_901) * 1e-9
    assert res.time_offset == pytest.approx(shift + 0.0063, abs=2e-4)
    # A part of the session, chosen on the IMU clock, works across epochs too.
    part = calibrate(*crop_session(sim.imu, sim.mocap, 10.0, 50.0), CalibrationOptions())
    assert part.time_offset == pytest.approx(shift + 0.0063, abs=5e-4)


def test_base_model_without_overlap_says_how_to_fix() -> None:
    sim = simulate_flight(SimConfig(seed=32, duration=30.0,
                                    mocap_time_origin_ns=10**18 + 5 * 10**12))
    with pytest.raises(InputError, match="base\\+time_offset"):
        calibrate(sim.imu, sim.mocap, CalibrationOptions(model=Model()))


def test_static_session_is_refused() -> None:
    n = 6000
    t = np.arange(n) / 200.0
    rng = np.random.default_rng(0)
    imu = ImuSamples(t, rng.normal(0, 1e-3, (n, 3)), np.tile([0, 0, 9.81], (n, 1)))
    m = n // 2
    mocap = MocapPoses(t[::2], np.tile([1.0, 0, 0, 0], (m, 1)), rng.normal(0, 2e-4, (m, 3)))
    with pytest.raises(ObservabilityError, match="static"):
        calibrate(imu, mocap, CalibrationOptions())


def test_too_short_session_is_refused() -> None:
    sim = simulate_flight(SimConfig(seed=33, duration=6.0))
    with pytest.raises(ObservabilityError, match="only 6.0 s"):
        calibrate(sim.imu, sim.mocap, CalibrationOptions())


def test_bad_options_are_input_errors() -> None:
    sim = simulate_flight(SimConfig(seed=34, duration=20.0))
    for opts in (CalibrationOptions(gravity=98.1), CalibrationOptions(window=0.01)):
        with pytest.raises(InputError):
            calibrate(sim.imu, sim.mocap, opts)
    with pytest.raises(InputError, match="--end 5 must be after --start 10"):
        crop_session(sim.imu, sim.mocap, 10.0, 5.0)


def yaw_only_session() -> tuple[ImuSamples, MocapPoses]:
    """90 s of a body that only yaws (no roll or pitch), with the truth below."""
    from mocap_calib.sim.trajectory import Trajectory, _SineSum

    rng = np.random.default_rng(5)

    def sines(amp: float, f: tuple[float, ...], offset: float = 0.0, rate: float = 0.0):
        k = len(f)
        return _SineSum(offset, rate, np.full(k, amp / k), np.asarray(f, float),
                        rng.uniform(0, 2 * np.pi, k))

    traj = Trajectory((sines(1.5, (0.11, 0.23, 0.31)), sines(1.5, (0.13, 0.19, 0.37)),
                       sines(0.4, (0.17, 0.29), offset=1.2)),
                      (sines(2.0, (0.07, 0.21), rate=0.3), sines(1e-4, (0.3,)),
                       sines(1e-4, (0.4,))))
    n = 90 * 200 + 1
    t = np.arange(n) / 200.0
    g_W = np.array([0.0, 0.0, -9.81])
    R_WI = traj.rotation(t)
    w = traj.angular_velocity_body(t)
    f = np.einsum("nji,nj->ni", R_WI, traj.acceleration(t) - g_W)
    gyro = w + 0.01 + rng.normal(0, 2.4e-3, (n, 3))
    accel = f + 0.05 + rng.normal(0, 2.8e-2, (n, 3))
    tm = t[::2]
    R_WM = traj.rotation(tm) @ YAW_R_MI.T
    p_WM = traj.position(tm) - R_WM @ YAW_P_MI + rng.normal(0, 5e-4, (len(tm), 3))
    return ImuSamples(t, gyro, accel), MocapPoses(tm, so3.rotmat_to_quat(R_WM), p_WM)


YAW_R_MI = so3.exp([0.3, -0.2, 0.1])
YAW_P_MI = np.array([0.05, -0.03, 0.08])


def test_unobservable_lever_arm_is_reported_not_returned() -> None:
    """A body that only yaws cannot show the lever arm's component along the yaw axis: the
    result must say so instead of printing a number, and still estimate the rest."""
    imu, mocap = yaw_only_session()
    res = calibrate(imu, mocap, CalibrationOptions(model=Model()))
    assert res.translation is None and "translation" in res.unobservable
    msg = res.unobservable["translation"]
    # Along the yaw axis: named by its sigma (component 2) or as the one rotation axis (in the
    # marker frame, R_MI e_z).
    shown = re.search(r"\[([-0-9., ]+)\] in the marker frame", msg)
    assert "component 2" in msg or (
        shown is not None and np.allclose(np.array(shown.group(1).split(","), dtype=float),
                                          YAW_R_MI[:, 2], atol=0.02)), msg
    assert res.sigma_translation is not None and res.sigma_translation[2] > 0.1
    # What the motion does excite is still estimated, and right: R_MI about the yaw axis shows
    # through the accelerometer (horizontal accelerations rotate with the yaw).
    R_est = so3.quat_to_rotmat(res.rotation_wxyz)
    assert np.degrees(np.linalg.norm(so3.log(YAW_R_MI.T @ R_est))) < 0.1
    assert np.abs(res.gyro_bias - 0.01).max() < 2e-4
    assert np.abs(res.accel_bias - 0.05).max() < 5e-3
