"""Stage 1, attitude factors: gyro preintegration vs mocap relative rotation.

Unknowns: the gyro bias ``b_g`` and ``R_MI``. Between keyframes ``i, j`` the mocap predicts the
IMU's relative rotation ``A = R_MI^T R_WM,i^T R_WM,j R_MI``; the gyro, preintegrated with the bias
``b0`` used for preintegration, gives ``dR`` with bias Jacobian ``J``. The factor's error is

    e = Log(A^T dR Exp(J (b_g - b0))).

The initial guess needs no user input: ``R_MI`` from aligning mocap and gyro angular velocities
(Kabsch), ``b_g`` from their means.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.gtsam_tools import (
    ABS_TOL,
    Huber,
    marginals,
    require_converged,
    run_lm,
)
from mocap_calib.core.model import so3
from mocap_calib.core.model.parameters import RANGE_SIGMA
from mocap_calib.core.model.preint import hermite, preintegrate_spans
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.prepare.session import PreparedSession, local_derivative
from mocap_calib.core.stages.figures import ResidualSeries, StageStats
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]

KEY_R = gtsam.symbol("r", 0)
KEY_BG = gtsam.symbol("w", 0)


def keyframes(tau: Array, spacing: float) -> NDArray[np.int64]:
    """Indices of mocap samples about ``spacing`` seconds apart."""
    targets = np.arange(tau[0], tau[-1], spacing)
    return np.unique(np.searchsorted(tau, targets))


def initial_rotation(s: PreparedSession, delta: float) -> tuple[Array, Array]:
    """``R_MI`` and ``b_g`` from mocap vs gyro angular velocity (Kabsch on centred vectors)."""
    dR = np.einsum("nji,njk->nik", s.R_WM[:-1], s.R_WM[1:])
    dt = np.diff(s.tau)
    w_M = so3.log(dR) / dt[:, None]
    t_mid = 0.5 * (s.tau[1:] + s.tau[:-1])
    _, w_M_s, valid = local_derivative(t_mid, np.cumsum(w_M * dt[:, None], axis=0), 3, s.gap)
    ok = (valid & (t_mid - delta > s.u[2]) & (t_mid - delta < s.u[-3]) & (dt < s.gap)
          & s.imu_clear(t_mid - delta, t_mid - delta))
    if ok.sum() < 50:
        raise ObservabilityError("fewer than 50 mocap samples overlap the IMU in time; check "
                                 "the files or the time offset")
    w_I = hermite(s.u, t_mid[ok] - delta)(s.gyro)
    w_M_s = w_M_s[ok]
    a = w_I - w_I.mean(axis=0)
    b = w_M_s - w_M_s.mean(axis=0)
    U, S, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    # With rotation about one axis only, R is arbitrary about that axis; the weak range prior
    # of the graphs keeps it in place and the marginals then report it as unobservable.
    b_g = w_I.mean(axis=0) - R.T @ w_M_s.mean(axis=0)
    return R, b_g


@dataclass
class AttitudeResult:
    """Stage 1 estimates and figures."""

    R_MI: Array
    gyro_bias: Array
    cov_rotation: Array
    cov_gyro_bias: Array
    stats: StageStats
    series: ResidualSeries


def attitude_errors(R: Array, b: Array, dRM: Array, dRI: Array, J: Array, b0: Array,
                    jacobians: bool = True) -> tuple[Array, Array | None, Array | None]:
    """Errors (n, 3) of the attitude factors and their Jacobians w.r.t. ``R`` (right
    perturbation) and ``b``."""
    A = np.einsum("ji,njk,kl->nil", R, dRM, R)
    dphi = np.einsum("nij,j->ni", J, b - b0)
    C = dRI @ so3.exp(dphi)
    E = np.einsum("nji,njk->nik", A, C)
    e = so3.log(E)
    if not jacobians:
        return e, None, None
    Jinv = so3.right_jacobian_inv(e)
    H_R = Jinv @ (np.swapaxes(C, 1, 2) - np.swapaxes(E, 1, 2))
    H_b = Jinv @ so3.right_jacobian(dphi) @ J
    return e, H_R, H_b


def _intervals(s: PreparedSession, delta: float, spacing: float) -> tuple[Array, Array]:
    """Start and end keyframes of every gap-free interval the IMU covers."""
    kf = keyframes(s.tau, spacing)
    i0, i1 = kf[:-1], kf[1:]
    ok = s.segments_without_gaps(i0, i1) & s.imu_covers(s.tau[i0], s.tau[i1], delta)
    i0, i1 = i0[ok], i1[ok]
    if len(i0) < 10:
        raise ObservabilityError(f"only {len(i0)} gap-free keyframe intervals overlap the IMU; "
                                 f"{s.gap_cause()}")
    return i0, i1


@dataclass
class _Solve:
    """The attitude solve's state: estimate, linearisation point and its preintegration."""

    R: Array
    b: Array
    b_lin: Array
    dRI: Array
    J: Array
    graph: gtsam.NonlinearFactorGraph | None = None
    sol: gtsam.Values | None = None
    iterations: int = 0
    evaluations: int = 0


def _solve(st: _Solve, dRM: Array, huber: Huber, R0: Array, bg0: Array, preint,
           max_iterations: int, on_iteration) -> _Solve:
    """Solve for ``R_MI`` and the gyro bias; re-preintegrate (up to three solves) while the
    bias moves beyond the first-order correction's comfort zone."""
    for _relinearise in range(3):
        def evaluate(v: gtsam.Values, dRI=st.dRI, J=st.J, b_lin=st.b_lin
                     ) -> tuple[Array, list[Array]]:
            R = v.atRot3(KEY_R).matrix()
            b = np.asarray(v.atVector(KEY_BG))
            e, HR, Hb = attitude_errors(R, b, dRM, dRI, J, b_lin)
            return e, [HR, Hb]

        batch = huber.factor(evaluate, [KEY_R, KEY_BG])
        graph = gtsam.NonlinearFactorGraph()
        for f in batch.factors():
            graph.add(f)
        graph.add(gtsam.PriorFactorRot3(
            KEY_R, gtsam.Rot3(R0), gtsam.noiseModel.Isotropic.Sigma(3, RANGE_SIGMA["rotation"])))
        graph.add(gtsam.PriorFactorVector(
            KEY_BG, bg0, gtsam.noiseModel.Isotropic.Sigma(3, RANGE_SIGMA["gyro_bias"])))
        init = gtsam.Values()
        init.insert(KEY_R, gtsam.Rot3(st.R))
        init.insert(KEY_BG, st.b)
        sol, rep = run_lm(graph, init, max_iterations, on_iteration,
                          absolute_tol=ABS_TOL)
        require_converged("attitude", rep, max_iterations)
        st.graph, st.sol = graph, sol
        st.iterations += rep.iterations
        st.evaluations += batch.evaluations
        st.R = sol.atRot3(KEY_R).matrix()
        st.b = np.asarray(sol.atVector(KEY_BG))
        if np.linalg.norm(st.b - st.b_lin) < 1e-3:
            break
        st.b_lin = st.b.copy()
        st.dRI, st.J = preint(st.b_lin)
    return st


def run_attitude_stage(s: PreparedSession, delta: float, noise: NoiseModel, spacing: float,
                       correct_fn, huber_k: float = 3.0, max_iterations: int = 30,
                       on_iteration=None) -> AttitudeResult:
    """Estimate ``R_MI`` and the gyro bias from attitude factors between keyframes.

    Args:
        s: prepared session.
        delta: mocap time minus IMU time (coarse).
        noise: noise densities.
        spacing: keyframe spacing (s).
        correct_fn: ``(gyro, accel, u, b_g) -> (w, f)``: the measurement model backwards with
            gyro bias ``b_g`` (other parameters fixed at their current values).
        huber_k: Huber threshold on the whitened 3-D error norm.
    """
    t0 = time.perf_counter()
    R0, bg0 = initial_rotation(s, delta)
    i0, i1 = _intervals(s, delta, spacing)
    dRM = np.einsum("nji,njk->nik", s.R_WM[i0], s.R_WM[i1])
    dt = s.tau[i1] - s.tau[i0]

    def preint(b: Array) -> tuple[Array, Array]:
        inc = preintegrate_spans(s.u, s.gyro, s.accel, s.tau[i0], s.tau[i1], delta,
                                 lambda g, a, u: correct_fn(g, a, u, b))
        return inc.dR, -np.einsum("nji,njk->nik", inc.dR, inc.A)

    sig = np.sqrt(2 * noise.mocap_rotation_sigma**2 + noise.gyroscope_noise_density**2 * dt
                  + noise.gyroscope_random_walk**2 * dt**3 / 3.0)
    huber = Huber(sig, huber_k)

    dRI, J = preint(bg0.copy())
    e_before, _, _ = attitude_errors(R0, bg0, dRM, dRI, J, bg0.copy(), jacobians=False)
    st = _solve(_Solve(R0, bg0, bg0.copy(), dRI, J), dRM, huber, R0, bg0, preint,
                max_iterations, on_iteration)
    marg = marginals(st.graph, st.sol)
    e_after, _, _ = attitude_errors(st.R, st.b, dRM, st.dRI, st.J, st.b_lin, jacobians=False)
    w, chi2 = huber.weights_and_chi2(e_after)
    t_mid = 0.5 * (s.tau[i0] + s.tau[i1])
    stats = StageStats(
        name="attitude", unit="deg",
        rms_before=np.degrees(np.sqrt(np.mean(e_before**2, axis=0))).tolist(),
        rms_after=np.degrees(np.sqrt(np.mean(e_after**2, axis=0))).tolist(),
        n_factors=len(i0), n_residuals=len(i0), outliers=int(np.sum(w < 0.5)),
        iterations=st.iterations, seconds=time.perf_counter() - t0,
        chi2_per_dof=chi2 / max(1, 3 * len(i0) - 6), batch_evaluations=st.evaluations)
    series = ResidualSeries(t_mid, np.degrees(e_before), np.degrees(e_after), w, "deg")
    return AttitudeResult(st.R, st.b, np.asarray(marg.marginalCovariance(KEY_R)),
                          np.asarray(marg.marginalCovariance(KEY_BG)), stats, series)
