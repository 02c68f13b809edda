"""The position-factor engine: Jacobians against numerical derivatives, the Kalman whitening
against a dense Gaussian likelihood, and the noise model against simulated truth."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.preint import hermite
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.engine import PositionProblem, Theta, compress, make_windows
from mocap_calib.core.position.threads import MIN_CHUNK_WINDOWS
from mocap_calib.core.prepare.session import local_derivative, prepare
from mocap_calib.core.threads import set_chunk_threads
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.sim.presets import preset_config

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

ALL_IMU_EFFECTS = ("base+time_offset+gravity_magnitude+gyro_scale_misalignment+"
                   "accel_scale_misalignment+gyro_g_sensitivity+gyro_bias_drift+accel_bias_drift+"
                   "clock_drift+accel_delay+accel_size_effect")


def _theta(sim, s, W, rng, R=None, p=None, g=None, gm=9.81, delta=None, eff=None, knots=None):
    tr = sim.truth
    R = so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])) if R is None else R
    p = np.array(tr["T_marker_imu"]["translation"]) if p is None else p
    g = np.array(tr["gravity_in_mocap"]) if g is None else g
    delta = s.clock_shift + 0.003 if delta is None else delta
    return Theta(R, p, g, gtsam.Unit3(np.array(tr["gravity_in_mocap"])).basis(), gm, delta,
                 eff, knots, 6.0)


def test_jacobians_match_numerical_derivatives(short_session):
    """Every column against the residuals' numerical derivative; the timing columns (clock
    offset, drift, accelerometer lag) are built from the motion's signal, here the samples
    themselves (the next test checks the smoothing)."""
    sim, s, v = short_session
    model = Model.parse(ALL_IMU_EFFECTS)
    win = make_windows(s, s.clock_shift + 0.003, 2.0, 200.0, v)
    pp = PositionProblem(s, model, NoiseModel(), win)
    pp._motion = (s.gyro, s.accel)
    rng = np.random.default_rng(0)
    eff = {e.name: rng.normal(0, 1e-3, e.dim) for e in model.units if e.in_effects}
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1))
    base = _theta(sim, s, win.count, rng, eff=eff, knots=knots)
    out = pp.evaluate(base, store=True)
    L = pp.layout
    eps = 1e-6

    def perturbed(name: str, i: int) -> Theta:
        th = _theta(sim, s, win.count, rng, eff={k: v.copy() for k, v in eff.items()},
                    knots=knots.copy())
        d3 = np.zeros(3)
        if name == "rotation":
            d3[i] = eps
            th.R_MI = th.R_MI @ so3.exp(d3)
        elif name == "translation":
            th.p_MI = th.p_MI + np.eye(3)[i] * eps
        elif name == "gravity":
            th.g_dir = gtsam.Unit3(th.g_dir).retract(np.eye(2)[i] * eps).point3()
        elif name == "time_offset":
            th.delta += eps
        elif name == "gravity_magnitude":
            th.g_mag += eps
        elif name == "knot":
            th.knots[:, i] += eps
        else:
            th.effects[name][i] += eps
        return th

    for name, dim in L.blocks:
        for i in range(dim):
            num = (pp.evaluate(perturbed(name, i), store=True).raw_r - out.raw_r) / eps
            ana = out.raw_J[..., L.slice(name).start + i]
            m = win.mask
            scale = np.abs(ana[m]).max()
            err = np.abs(num[m] - ana[m]).max()
            assert err < 2e-3 * scale + 1e-6, f"{name}[{i}]: error {err:.3g} vs scale {scale:.3g}"


def _shift_information(sim) -> tuple[float, float]:
    """The clock offset's sigma (ms) from the window factors' information at the true
    parameters (every window's knot and the other shared parameters eliminated), with the
    timing column built from the raw samples and from the motion's signal."""
    s = prepare(sim.imu, sim.mocap)
    _, v, _ = local_derivative(s.tau, s.p_WM, 5, s.gap)
    tr = sim.truth
    delta = s.clock_shift + tr["time_offset"]
    win = make_windows(s, delta, 5.0, 120.0, v)
    iu = np.searchsorted(s.u, win.start)
    th = Theta(so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])),
               np.array(tr["T_marker_imu"]["translation"]), np.array(tr["gravity_in_mocap"]),
               np.eye(3)[:, :2], 9.81, delta, {},
               np.c_[sim.gyro_bias_true[iu], sim.accel_bias_true[iu]], 15.0)
    noise = NoiseModel(accelerometer_noise_density=0.025, mocap_position_sigma=5e-4,
                       mocap_rotation_sigma=float(np.radians(0.2)), mocap_noise_corr_time=0.3,
                       mocap_noise_corr_fraction=0.99)
    sig = []
    for raw in (True, False):
        pp = PositionProblem(s, Model.parse("base+time_offset"), noise, win)
        if raw:
            pp._motion = (s.gyro, s.accel)
        G = pp.evaluate(th).gram[:, :-1, :-1]
        k = pp.layout.slice("knot")
        g = slice(0, k.start)
        S = sum(Gw[g, g] - Gw[g, k] @ np.linalg.solve(Gw[k, k], Gw[k, g]) for Gw in G)
        t = pp.layout.slice("time_offset").start
        sig.append(1e3 * float(np.sqrt(np.linalg.inv(S)[t, t])))
    return sig[0], sig[1]


@pytest.mark.parametrize("seed", [5, 7])
def test_rotor_vibration_adds_no_clock_information(seed):
    """Rotor vibration is noise of the samples: it must not sharpen the clock offset. A flight
    with the ``flying`` preset's vibration against its twin without it (every other draw the
    same): from the raw samples the vibration's rate of change counts as information (its
    sigma a third smaller than the twin's), from the motion's signal it does not."""
    vib = simulate_flight(preset_config("flying", seed=seed, duration=30.0))
    twin = simulate_flight(preset_config("flying", seed=seed, duration=30.0,
                                         vibration={"accel_rms": 0.0, "gyro_rms": 0.0}))
    raw_vib, motion_vib = _shift_information(vib)
    raw_twin, motion_twin = _shift_information(twin)
    assert raw_vib < 0.8 * raw_twin  # the raw samples' column: the effect is there
    assert motion_vib > 0.95 * motion_twin
    assert motion_twin == pytest.approx(raw_twin, rel=0.05)  # without vibration: as before


def test_timing_columns_follow_the_motion_not_the_samples():
    """The clock offset's column is the residuals' derivative when only the motion's signal
    moves in time (the samples plus the motion's signal shifted, minus it unshifted), not
    when the samples do (rotor vibration: the ``flying`` preset)."""
    sim = simulate_flight(preset_config("flying", seed=3, duration=12.0))
    s = prepare(sim.imu, sim.mocap)
    _, v, _ = local_derivative(s.tau, s.p_WM, 5, s.gap)
    model = Model.parse("base+time_offset")
    win = make_windows(s, s.clock_shift + 0.005, 2.0, 200.0, v)
    pp = PositionProblem(s, model, NoiseModel(), win)
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1))
    th = _theta(sim, s, win.count, None, eff={}, knots=knots, delta=s.clock_shift + 0.005)
    out = pp.evaluate(th, store=True)
    g_m, a_m = pp.motion_samples()
    eps = 1e-6
    at = hermite(s.u, s.u - eps)  # reading at u - eps: the clock offset grown by eps
    moved = replace(s, gyro=s.gyro + at(g_m) - hermite(s.u, s.u)(g_m),
                    accel=s.accel + at(a_m) - hermite(s.u, s.u)(a_m))
    shifted = PositionProblem(moved, model, NoiseModel(), win)
    shifted._motion = pp.motion_samples()
    num = (shifted.evaluate(th, store=True).raw_r - out.raw_r) / eps
    col = out.raw_J[..., pp.layout.slice("time_offset").start]
    m = win.mask
    m[:, 0] = False
    scale = np.abs(col[m]).max()
    assert np.abs(num[m] - col[m]).max() < 5e-3 * scale  # (the raw samples: 0.19)
    raw = pp.evaluate(replace(th, delta=th.delta + eps), store=True).raw_r
    assert np.abs((raw - out.raw_r) / eps - col)[m].max() > 0.1 * scale  # not the samples'


def _mocap_noise(n: int, noise: NoiseModel, axes: np.ndarray) -> np.ndarray:
    """(n, 6, 6) covariance of the residuals' mocap noise, written out: independent attitude
    noise per IMU-frame axis and position noise per world axis (the measured marker position
    is compared with the one the trajectory predicts, so the attitude noise does not reach
    it)."""
    var = np.r_[np.full(3, noise.mocap_rotation_sigma**2),
                np.full(3, noise.mocap_position_sigma**2)]
    return np.tile(np.diag(var * axes), (n, 1, 1))


def _observation(th: Theta, Rbar: np.ndarray) -> np.ndarray:
    """(n, 6, 15) rows of the residuals on the error state, written out: the attitude rows see
    the attitude error; the predicted marker position p_bar - R_bar Exp(a) R_MI^T p_MI moves by
    R_bar [R_MI^T p_MI]x a with the attitude error a, and by the position error directly."""
    H = np.zeros((len(Rbar), 6, 15))
    H[:, 0:3, 0:3] = np.eye(3)
    H[:, 3:6, 3:6] = np.eye(3)
    H[:, 3:6, 0:3] = Rbar @ so3.hat(th.R_MI.T @ th.p_MI)
    return H


def _process_noise(noise: NoiseModel, R: np.ndarray, h: float) -> np.ndarray:
    """A step's process noise written out: white gyro noise on the attitude, the
    accelerometer's (per IMU axis, turned into the world by the nominal attitude ``R`` at the
    step's start) integrated into velocity and position, the bias random walks."""
    Qa = noise.accelerometer_noise_density**2 * (
        R @ np.diag(noise.accelerometer_axis_scale) @ R.T)
    Q = np.zeros((15, 15))
    Q[0:3, 0:3] = noise.gyroscope_noise_density**2 * h * np.eye(3)
    Q[3:6, 3:6] = Qa * h**3 / 3.0
    Q[6:9, 6:9] = Qa * h
    Q[3:6, 6:9] = Q[6:9, 3:6] = Qa * h**2 / 2.0
    Q[9:12, 9:12] = noise.gyroscope_random_walk**2 * h * np.eye(3)
    Q[12:15, 12:15] = noise.accelerometer_random_walk**2 * h * np.eye(3)
    return Q


def _state_covs(ex: dict, w: int, m1: int, noise: NoiseModel) -> list[np.ndarray]:
    """The error state's covariance at every sample of window ``w`` from its diffuse start,
    through the filter's transitions and the process noise written out (checked against the
    engine's)."""
    F = ex["F"][w]
    P = np.diag(np.r_[np.full(3, 1.0), np.full(3, 1.0), np.full(3, 0.25), np.zeros(6)])
    Ps = [P]
    for k in range(m1 - 1):
        Q = _process_noise(noise, ex["Rbar"][w, k], ex["h"][w, k])
        np.testing.assert_allclose(ex["Q"][w, k], Q, rtol=1e-9, atol=1e-12 * np.abs(Q).max())
        P = F[k] @ P @ F[k].T + Q
        Ps.append(P)
    return Ps


def _dense_cov(ex: dict, w: int, m1: int, noise: NoiseModel, full: np.ndarray, rho: float,
               Rn: np.ndarray, wt: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Dense covariance of all residuals of window ``w`` from the filter's state-space model
    (``ex``, the engine's extras), the observation rows ``H`` and the mocap noise written out
    (``full``, ``Rn``)."""
    F = ex["F"][w]
    Ps = _state_covs(ex, w, m1, noise)
    # The correlated mocap noise, written out as its own Gauss-Markov sequence.
    if noise.mocap_correlated:
        Fm, Qm, Pm = ex["Fm"][w], ex["Qm"][w], [ex["Pm0"][w]]
        np.testing.assert_allclose(Pm[0], rho * full[0], rtol=1e-12, atol=1e-20)
        for k in range(m1 - 1):
            Pm.append(Fm[k] @ Pm[-1] @ Fm[k].T + Qm[k])
            # The AR(1) part stays stationary: at every sample, rho times the noise there.
            np.testing.assert_allclose(Pm[-1], rho * full[k + 1], rtol=1e-9,
                                       atol=1e-12 * np.abs(full[k + 1]).max())
    n = 6 * m1
    C = np.zeros((n, n))
    for k in range(m1):
        Phi = np.eye(15)
        Phm = np.eye(6)
        for j in range(k, m1):
            if j > k:
                Phi = F[j - 1] @ Phi
                Phm = ex["Fm"][w][j - 1] @ Phm if noise.mocap_correlated else Phm
            block = H[j] @ Phi @ Ps[k] @ H[k].T
            if noise.mocap_correlated:
                block = block + Phm @ Pm[k]
            C[6 * j:6 * j + 6, 6 * k:6 * k + 6] = block
            C[6 * k:6 * k + 6, 6 * j:6 * j + 6] = block.T
        C[6 * k:6 * k + 6, 6 * k:6 * k + 6] += Rn[k] / wt[k]
    return C


@pytest.mark.parametrize("noise, axes", [
    (NoiseModel(), np.ones(6)),
    # Per-axis mocap noise: each attitude (IMU frame) and position (world) axis its own level.
    (NoiseModel(), np.array([0.3, 1.0, 4.0, 2.0, 0.5, 1.5])),
    # Mocap noise correlated over 50 ms (70 % of its variance): six more filter states.
    (NoiseModel(mocap_position_sigma=1e-3, mocap_noise_corr_time=0.05,
                mocap_noise_corr_fraction=0.7), np.ones(6)),
    (NoiseModel(mocap_position_sigma=1e-3, mocap_noise_corr_time=0.05,
                mocap_noise_corr_fraction=0.7), np.array([2.0, 0.5, 1.0, 0.25, 3.0, 1.0])),
    # The accelerometer noisier along one IMU axis (a drone's thrust axis).
    (NoiseModel(accelerometer_axis_scale=(0.5, 0.7, 2.9)), np.ones(6)),
    (NoiseModel(mocap_position_sigma=1e-3, mocap_noise_corr_time=0.05,
                mocap_noise_corr_fraction=0.7, accelerometer_axis_scale=(3.0, 0.5, 0.6)),
     np.array([2.0, 0.5, 1.0, 0.25, 3.0, 1.0]))],
    ids=["white", "white-axes", "correlated", "correlated-axes", "accel-axes",
         "correlated-accel-axes"])
def test_kalman_whitening_equals_dense_gaussian_likelihood(short_session, noise, axes):
    sim, s, v = short_session
    model = Model.parse("base+time_offset")
    win = make_windows(s, s.clock_shift + 0.003, 0.15, 200.0, v, min_samples=10)
    pp = PositionProblem(s, model, noise, win)
    pp.mocap_axis_scale = axes
    pp.weights[0, 5] = 0.3  # a robust weight must enter as an inflated (white) noise
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1)) + 1e-3
    th = _theta(sim, s, win.count, None, eff={}, knots=knots)
    out = pp.evaluate(th, store=True)
    ex = out.extras
    rho = noise.mocap_noise_corr_fraction if noise.mocap_correlated else 0.0
    for w in range(3):
        m1 = int(win.mask[w].sum())
        wt = ex["weights"][w]
        # The mocap noise from its definition, not from the engine: white part here, the
        # correlated part's stationary covariance below.
        full = _mocap_noise(win.mask.shape[1], noise, axes)
        Rn = (1.0 - rho) * full
        np.testing.assert_allclose(ex["Rn"][w][:m1], Rn[:m1], rtol=1e-12, atol=1e-20)
        H = _observation(th, ex["Rbar"][w])
        np.testing.assert_allclose(ex["Hp"][w][:m1], H[:m1, 3:6, 0:3], rtol=1e-12, atol=1e-15)
        C = _dense_cov(ex, w, m1, noise, full, rho, Rn, wt, H)
        n = 6 * m1
        r = out.raw_r[w, :m1].reshape(-1)
        J = out.raw_J[w, :m1].reshape(n, -1)
        A = np.concatenate([J, r[:, None]], axis=1)
        dense = A.T @ np.linalg.solve(C, A)
        np.testing.assert_allclose(out.gram[w], dense, rtol=1e-6,
                                   atol=1e-9 * np.abs(dense).max())
        assert out.chi2[w] == pytest.approx(r @ np.linalg.solve(C, r), rel=1e-6)
        assert out.logdet[w] == pytest.approx(np.linalg.slogdet(C)[1], rel=1e-9, abs=1e-6)
        # The whitened innovations are the dense Cholesky whitening of the residuals, component
        # by component (what the per-axis noise estimate reads).
        e_dense = np.linalg.solve(np.linalg.cholesky(C), r).reshape(m1, 6)
        np.testing.assert_allclose(out.e_white[w, :m1], e_dense, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("noise", [
    NoiseModel(),
    NoiseModel(mocap_position_sigma=1e-3, mocap_noise_corr_time=0.05,
               mocap_noise_corr_fraction=0.7)], ids=["white", "correlated"])
def test_frozen_whitening_is_the_recorded_dense_likelihood(short_session, noise):
    """A frozen whitening (recorded at one point, replayed at another) makes the cost the
    weighted least squares of the new residuals with the recorded point's dense covariance;
    the replay keeps only the recorded increments, so this checks it rebuilds the operator."""
    sim, s, v = short_session
    win = make_windows(s, s.clock_shift + 0.003, 0.15, 200.0, v, min_samples=10)
    pp = PositionProblem(s, Model.parse("base+time_offset"), noise, win)
    pp.weights[1, 4] = 0.3
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1))
    th0 = _theta(sim, s, win.count, None, eff={}, knots=knots + 1e-3)
    th1 = _theta(sim, s, win.count, None, eff={}, knots=knots + 3e-3, delta=s.clock_shift + 0.004)
    th1.R_MI = th1.R_MI @ so3.exp(np.radians([0.5, -0.3, 0.2]))
    th1.p_MI = th1.p_MI + np.array([2e-3, -1e-3, 1e-3])
    pp.freeze_whitening(True)
    rec = pp.evaluate(th0, store=True)
    frozen = pp.evaluate(th1, store=True)
    pp.freeze_whitening(False)
    fresh = pp.evaluate(th1)
    rho = noise.mocap_noise_corr_fraction if noise.mocap_correlated else 0.0
    for w in range(3):
        m1 = int(win.mask[w].sum())
        full = _mocap_noise(win.mask.shape[1], noise, np.ones(6))
        H0 = _observation(th0, rec.extras["Rbar"][w])
        C0 = _dense_cov(rec.extras, w, m1, noise, full, rho, (1.0 - rho) * full,
                        rec.extras["weights"][w], H0)
        r1 = frozen.raw_r[w, :m1].reshape(-1)
        A1 = np.concatenate([frozen.raw_J[w, :m1].reshape(6 * m1, -1), r1[:, None]], axis=1)
        dense = A1.T @ np.linalg.solve(C0, A1)
        # The record keeps the increments in single precision (the dense covariance here is
        # built from the double-precision ones): agreement to ~1e-7 relative, not 1e-12.
        np.testing.assert_allclose(frozen.gram[w], dense, rtol=1e-5,
                                   atol=1e-7 * np.abs(dense).max())
        e_dense = np.linalg.solve(np.linalg.cholesky(C0), r1).reshape(m1, 6)
        np.testing.assert_allclose(frozen.e_white[w, :m1], e_dense, rtol=1e-5, atol=1e-6)
        # ... which is not the whitening at the new point (the test can tell them apart: 20x
        # the agreement asked above; the whitening moves with the attitudes and increments).
        assert np.abs(fresh.e_white[w, :m1] - e_dense).max() > 2e-5


@pytest.mark.parametrize("noise", [
    NoiseModel(accelerometer_random_walk=0.3),
    NoiseModel(mocap_position_sigma=1e-3, mocap_noise_corr_time=0.05,
               mocap_noise_corr_fraction=0.7, accelerometer_random_walk=0.3)],
    ids=["white", "correlated"])
def test_bias_integral_states_equal_dense_gaussian_conditioning(short_session, noise):
    """The six states the filter adds for the bias error's time integral (the session-mean
    bias's posterior): its mean per column of ``[J | r]``, its covariance and its covariance
    with the end bias equal Gaussian conditioning of the written-out state sequence on all the
    window's residuals (the integral a left Riemann sum of the bias over the steps; a random
    walk 100x the data sheet's so that it matters inside a 0.15 s window)."""
    sim, s, v = short_session
    win = make_windows(s, s.clock_shift + 0.003, 0.15, 200.0, v, min_samples=10)
    pp = PositionProblem(s, Model.parse("base+time_offset"), noise, win)
    pp.weights[0, 3] = 0.3
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1)) + 1e-3
    th = _theta(sim, s, win.count, None, eff={}, knots=knots)
    out = pp.evaluate(th, store=True, integral=True)
    plain = pp.evaluate(th)
    # The integral states change nothing else.
    np.testing.assert_array_equal(out.gram, plain.gram)
    np.testing.assert_array_equal(out.term_P, plain.term_P)
    assert out.int_X is not None and out.int_P is not None and plain.int_X is None
    ex = out.extras
    rho = noise.mocap_noise_corr_fraction if noise.mocap_correlated else 0.0
    for w in range(3):
        m1 = int(win.mask[w].sum())
        full = _mocap_noise(win.mask.shape[1], noise, np.ones(6))
        H = _observation(th, ex["Rbar"][w])
        C = _dense_cov(ex, w, m1, noise, full, rho, (1.0 - rho) * full, ex["weights"][w], H)
        # Every pair of states, written out: Cov(x_j, x_k) = Phi(j <- k) P_k for j >= k.
        F = ex["F"][w]
        Ps = _state_covs(ex, w, m1, noise)
        X = np.zeros((15 * m1, 15 * m1))
        for k in range(m1):
            Phi = np.eye(15)
            for j in range(k, m1):
                if j > k:
                    Phi = F[j - 1] @ Phi
                X[15 * j:15 * j + 15, 15 * k:15 * k + 15] = Phi @ Ps[k]
                X[15 * k:15 * k + 15, 15 * j:15 * j + 15] = (Phi @ Ps[k]).T
        Hb = np.zeros((6 * m1, 15 * m1))
        L = np.zeros((6, 15 * m1))  # the integral: sum of h_k times the bias at sample k
        for k in range(m1):
            Hb[6 * k:6 * k + 6, 15 * k:15 * k + 15] = H[k]
            if k < m1 - 1:
                L[:, 15 * k + 9:15 * k + 15] = ex["h"][w, k] * np.eye(6)
        E = np.zeros((6, 15 * m1))  # the bias at the window's last sample
        E[:, 15 * (m1 - 1) + 9:15 * m1] = np.eye(6)
        cy = L @ X @ Hb.T
        ce = E @ X @ Hb.T
        A = np.concatenate([out.raw_J[w, :m1].reshape(6 * m1, -1),
                            out.raw_r[w, :m1].reshape(-1, 1)], axis=1)
        mean = cy @ np.linalg.solve(C, A)
        cov = L @ X @ L.T - cy @ np.linalg.solve(C, cy.T)
        cross = L @ X @ E.T - cy @ np.linalg.solve(C, ce.T)
        np.testing.assert_allclose(out.int_X[w], mean, rtol=1e-6,
                                   atol=1e-7 * np.abs(mean).max())
        np.testing.assert_allclose(out.int_P[w, :, 0:6], cov, rtol=1e-6,
                                   atol=1e-7 * np.abs(cov).max())
        np.testing.assert_allclose(out.int_P[w, :, 6:12], cross, rtol=1e-6,
                                   atol=1e-7 * np.abs(cross).max())


def test_per_axis_mocap_noise_scale_recovers_a_misscaled_model():
    """At the true parameters of a simulated flight (isotropic mocap noise), a model whose
    mocap variances are wrong by a different factor per axis: the per-axis estimate reads the
    inverse factors off the whitened innovations; with unit factors it reads ones, and the
    two-level estimate is the same as before (the defaults change nothing)."""
    sim = simulate_flight(SimConfig(seed=5, duration=60.0))
    s = prepare(sim.imu, sim.mocap)
    _, v, _ = local_derivative(s.tau, s.p_WM, 5, s.gap)
    win = make_windows(s, s.clock_shift, 2.0, 200.0, v)
    iu = np.searchsorted(s.u, win.start)
    knots = np.c_[sim.gyro_bias_true[iu], sim.accel_bias_true[iu]]
    tr = sim.truth
    th = Theta(so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])),
               np.array(tr["T_marker_imu"]["translation"]), np.array(tr["gravity_in_mocap"]),
               np.eye(3)[:, :2], 9.81, s.clock_shift, {}, knots, 30.0)
    pp = PositionProblem(s, Model(), NoiseModel(), win)
    unit = pp.evaluate(th)
    np.testing.assert_allclose(pp.mocap_noise_scale_axes(unit), np.ones(6), atol=0.12)
    for axes in (np.array([0.25, 1.0, 4.0, 4.0, 1.0, 0.25]), np.array([2, 2, 2, 0.5, 0.5, 0.5])):
        pp.mocap_axis_scale = axes
        got = pp.mocap_noise_scale_axes(pp.evaluate(th))
        np.testing.assert_allclose(got, 1.0 / axes, rtol=0.15)
    pp.mocap_axis_scale = np.ones(6)
    again = pp.evaluate(th)
    np.testing.assert_array_equal(again.gram, unit.gram)
    assert pp.mocap_noise_scale(again) == pp.mocap_noise_scale(unit)


def test_compressed_factor_reproduces_the_quadratic_cost():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(200, 7)) * np.logspace(-3, 3, 7)
    r = rng.normal(size=200)
    A = np.concatenate([J, r[:, None]], axis=1)
    e, H = compress((A.T @ A)[None])
    for _ in range(5):
        d = rng.normal(size=7) / np.logspace(-3, 3, 7)
        assert np.sum((e[0] + H[0] @ d) ** 2) == pytest.approx(np.sum((r + J @ d) ** 2), rel=1e-8)


@pytest.mark.parametrize("length", [2.0, 8.0])
def test_noise_model_is_consistent_at_the_truth(length):
    """At the true parameters the whitened residuals are standard normal: chi2/dof ~ 1 within
    its sampling scatter, with bias random walk inside windows of any length."""
    sim = simulate_flight(SimConfig(seed=5, duration=60.0))
    s = prepare(sim.imu, sim.mocap)
    _, v, _ = local_derivative(s.tau, s.p_WM, 5, s.gap)
    win = make_windows(s, s.clock_shift, length, 200.0, v)
    pp = PositionProblem(s, Model(), NoiseModel(), win)
    iu = np.searchsorted(s.u, win.start)
    knots = np.c_[sim.gyro_bias_true[iu], sim.accel_bias_true[iu]]
    tr = sim.truth
    th = Theta(so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])),
               np.array(tr["T_marker_imu"]["translation"]), np.array(tr["gravity_in_mocap"]),
               np.eye(3)[:, :2], 9.81, s.clock_shift, {}, knots, 30.0)
    out = pp.evaluate(th)
    dof = float(np.sum(6 * win.mask.sum(axis=1) - 9))
    ratio = out.chi2.sum() / dof
    assert abs(ratio - 1.0) < 4.0 * np.sqrt(2.0 / dof) + 0.01


@pytest.mark.parametrize("noise", [
    NoiseModel(),
    NoiseModel(mocap_position_sigma=1e-3, mocap_noise_corr_time=0.05,
               mocap_noise_corr_fraction=0.7)], ids=["white", "correlated"])
def test_likelihood_pass_equals_the_full_evaluation(short_session, noise):
    """The noise-model choice uses a filter pass without Jacobian columns: it must give the
    full evaluation's chi2 + log det, window by window."""
    sim, s, v = short_session
    win = make_windows(s, s.clock_shift + 0.003, 0.5, 200.0, v, min_samples=10)
    pp = PositionProblem(s, Model.parse("base+time_offset"), noise, win)
    pp.weights[1, 7] = 0.2
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1)) + 1e-3
    th = _theta(sim, s, win.count, None, eff={}, knots=knots)
    full = pp.evaluate(th)
    # Batched with models of both kinds (white and correlated run as separate batches).
    other = replace(noise, mocap_noise_corr_time=0.2 if not noise.mocap_correlated else 0.0,
                    mocap_noise_corr_fraction=0.5 if not noise.mocap_correlated else 0.0)
    (chi2, logdet), _, (chi2_b, logdet_b) = pp.likelihoods(
        th, [noise, other, replace(noise, mocap_position_sigma=noise.mocap_position_sigma)])
    for c2, ld in ((chi2, logdet), (chi2_b, logdet_b)):
        np.testing.assert_allclose(c2, full.chi2, rtol=1e-8)
        np.testing.assert_allclose(ld, full.logdet, rtol=1e-8, atol=1e-6)


def test_chunk_threads_do_not_change_the_numbers(short_session):
    """Windows are evaluated in two chunks on threads: the numbers must not depend on the
    thread count (bit for bit) nor on the split (to rounding)."""
    sim, s, v = short_session
    win = make_windows(s, s.clock_shift + 0.003, 0.3, 200.0, v, min_samples=10)
    assert win.count >= 2 * MIN_CHUNK_WINDOWS
    noise = NoiseModel(mocap_noise_corr_time=0.1, mocap_noise_corr_fraction=0.5)
    split = PositionProblem(s, Model.parse("base+time_offset"), noise, win)
    whole = PositionProblem(s, Model.parse("base+time_offset"), noise, win, split=False)
    assert (len(split.chunks), len(whole.chunks)) == (2, 1)
    tr = sim.truth
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (win.count, 1))
    th = _theta(sim, s, win.count, None, eff={}, knots=knots)
    previous = set_chunk_threads(2)
    try:
        two = split.evaluate(th)
        set_chunk_threads(1)
        one = split.evaluate(th)
    finally:
        set_chunk_threads(previous)
    ref = whole.evaluate(th)
    for f in ("gram", "chi2", "logdet", "d_raw", "innovation"):
        np.testing.assert_array_equal(getattr(two, f), getattr(one, f))
        np.testing.assert_allclose(getattr(two, f), getattr(ref, f), rtol=1e-10, atol=1e-12)
