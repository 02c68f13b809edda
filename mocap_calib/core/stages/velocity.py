"""Stage 2, velocity factors: accel preintegration vs mocap velocity change.

Unknowns: the accel bias ``b_a``, the lever arm ``p_MI`` and the gravity direction in the mocap
world (a ``Unit3``: two degrees of freedom). ``R_MI`` and ``b_g`` come from stage 1. The IMU's
velocity at a keyframe is the marker's (a local quadratic fit of the mocap positions) plus the
lever-arm term ``R_WM [w_M]x p_MI`` with ``w_M = R_MI w`` from the corrected gyro. Between
keyframes ``i, j``

    e = v_WI,j - v_WI,i - g_W dt - R_WI,i (dv - A (b_a - b0)).

The initial guess is the linear least-squares solution with ``g_W`` as a free 3-vector.
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
from mocap_calib.core.stages.attitude import keyframes
from mocap_calib.core.stages.figures import ResidualSeries, StageStats
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]

KEY_BA = gtsam.symbol("a", 0)
KEY_P = gtsam.symbol("p", 0)
KEY_G = gtsam.symbol("g", 0)


@dataclass
class VelocityResult:
    """Stage 2 estimates and figures."""

    accel_bias: Array
    p_MI: Array
    gravity_dir: Array
    gravity_norm_free: float  # |g_W| of the linear solution: a units / sign sanity check
    cov_accel_bias: Array
    cov_translation: Array
    cov_gravity: Array
    stats: StageStats
    series: ResidualSeries


@dataclass(frozen=True)
class _Data:
    dvM: Array  # marker velocity change (n, 3)
    LM: Array  # (n, 3, 3): d(v_WI,j - v_WI,i)/d p_MI
    R_i: Array  # (n, 3, 3) R_WI at i
    dv: Array  # (n, 3) preintegrated velocity increment at b0
    A: Array  # (n, 3, 3) -d dv / d b_a
    dt: Array


def velocity_errors(d: _Data, b: Array, p: Array, g_vec: Array, b0: Array) -> Array:
    pred = d.dv - np.einsum("nij,j->ni", d.A, b - b0)
    return (d.dvM + np.einsum("nij,j->ni", d.LM, p) - g_vec * d.dt[:, None]
            - np.einsum("nij,nj->ni", d.R_i, pred))


def velocity_factor(data: _Data, b: Array, p: Array, u3: gtsam.Unit3, gravity: float,
                    b_lin: Array) -> tuple[Array, Array, Array, Array]:
    """Errors of all velocity factors and their Jacobians (accel bias, ``p_MI``, gravity
    direction in its Unit3 tangent space): what the stage's factors evaluate."""
    e = velocity_errors(data, b, p, gravity * u3.point3(), b_lin)
    Hb = np.einsum("nij,njk->nik", data.R_i, data.A)
    Hg = -gravity * data.dt[:, None, None] * u3.basis()[None]
    return e, Hb, data.LM, Hg


@dataclass
class _Solve:
    """The velocity solve's state: estimate, linearisation point and the factors' data."""

    b: Array
    p: Array
    g_dir: Array
    b_lin: Array
    data: _Data
    graph: gtsam.NonlinearFactorGraph | None = None
    sol: gtsam.Values | None = None
    iterations: int = 0
    evaluations: int = 0


def _solve(st: _Solve, huber: Huber, start: tuple[Array, Array, Array], gravity: float, preint,
           max_iterations: int, on_iteration) -> _Solve:
    """Solve for ``b_a``, ``p_MI`` and the gravity direction; re-preintegrate (up to three
    solves) while the accel bias moves by more than 0.05 m/s^2. ``start``: the linear
    start's ``(b_a, p_MI, gravity direction)``, the range priors' centres."""
    b0, p0, g0 = start
    for _relinearise in range(3):
        def evaluate(v: gtsam.Values, data=st.data, b_lin=st.b_lin
                     ) -> tuple[Array, list[Array]]:
            e, Hb, Hp, Hg = velocity_factor(data, np.asarray(v.atVector(KEY_BA)),
                                            np.asarray(v.atPoint3(KEY_P)), v.atUnit3(KEY_G),
                                            gravity, b_lin)
            return e, [Hb, Hp, Hg]

        batch = huber.factor(evaluate, [KEY_BA, KEY_P, KEY_G])
        graph = gtsam.NonlinearFactorGraph()
        for f in batch.factors():
            graph.add(f)
        graph.add(gtsam.PriorFactorVector(
            KEY_BA, b0, gtsam.noiseModel.Isotropic.Sigma(3, RANGE_SIGMA["accel_bias"])))
        graph.add(gtsam.PriorFactorPoint3(
            KEY_P, p0, gtsam.noiseModel.Isotropic.Sigma(3, RANGE_SIGMA["translation"])))
        graph.add(gtsam.PriorFactorUnit3(
            KEY_G, gtsam.Unit3(g0),
            gtsam.noiseModel.Isotropic.Sigma(2, RANGE_SIGMA["gravity"])))
        init = gtsam.Values()
        init.insert(KEY_BA, st.b)
        init.insert(KEY_P, gtsam.Point3(*st.p))
        init.insert(KEY_G, gtsam.Unit3(st.g_dir))
        sol, rep = run_lm(graph, init, max_iterations, on_iteration,
                          absolute_tol=ABS_TOL)
        require_converged("velocity", rep, max_iterations)
        st.graph, st.sol = graph, sol
        st.iterations += rep.iterations
        st.evaluations += batch.evaluations
        st.b = np.asarray(sol.atVector(KEY_BA))
        st.p = np.asarray(sol.atPoint3(KEY_P))
        st.g_dir = sol.atUnit3(KEY_G).point3()
        if np.linalg.norm(st.b - st.b_lin) < 0.05:
            break
        st.b_lin = st.b.copy()
        dv, A = preint(st.b_lin)
        d = st.data
        st.data = _Data(d.dvM, d.LM, d.R_i, dv, A, d.dt)
    return st


def run_velocity_stage(s: PreparedSession, delta: float, noise: NoiseModel, spacing: float,
                       R_MI: Array, correct_fn, gravity: float, huber_k: float = 3.0,
                       max_iterations: int = 30, on_iteration=None) -> VelocityResult:
    """Estimate ``b_a``, ``p_MI`` and the gravity direction from velocity factors.

    Args:
        s: prepared session; delta: mocap time minus IMU time.
        noise: noise densities; spacing: keyframe spacing (s).
        R_MI: from stage 1.
        correct_fn: ``(gyro, accel, u, b_a) -> (w, f)``: the measurement model backwards with
            accel bias ``b_a`` (gyro bias and the rest fixed).
        gravity: assumed ``|g|``.
    """
    t0 = time.perf_counter()
    half = max(2, int(round(0.05 * s.mocap_rate)))  # +-50 ms quadratic fit
    vM, kf, i0, i1 = _intervals(s, delta, spacing, half)
    dt = s.tau[i1] - s.tau[i0]
    w_kf = correct_fn(*(hermite(s.u, s.tau[kf] - delta)(x) for x in (s.gyro, s.accel)),
                      s.tau[kf] - delta, np.zeros(3))[0]
    w_M = w_kf @ R_MI.T
    lever = s.R_WM[kf] @ so3.hat(w_M)  # v_WI = v_WM + lever p_MI
    pos = {k: n for n, k in enumerate(kf)}
    j0 = np.array([pos[k] for k in i0])
    j1 = np.array([pos[k] for k in i1])
    R_i = s.R_WM[i0] @ R_MI

    def preint(b: Array) -> tuple[Array, Array]:
        inc = preintegrate_spans(s.u, s.gyro, s.accel, s.tau[i0], s.tau[i1], delta,
                                 lambda g, a, u: correct_fn(g, a, u, b))
        return inc.dv, inc.A

    b_lin = np.zeros(3)
    dv, A = preint(b_lin)
    data = _Data(vM[i1] - vM[i0], lever[j1] - lever[j0], R_i, dv, A, dt)

    p0, g_free, b0, g_norm = _linear_start(data, gravity)
    n = len(i0)

    # Noise: velocity fits at both ends, accel noise, attitude noise times the increment.
    sv2 = 12.0 * noise.mocap_position_sigma**2 / (
        (2 * half + 1) * ((2 * half + 1) ** 2 - 1) / s.mocap_rate**2)
    sig = np.sqrt(2 * sv2 + noise.accelerometer_noise_density**2 * dt
                  + noise.accelerometer_random_walk**2 * dt**3 / 3.0
                  + noise.mocap_rotation_sigma**2 * np.sum(dv**2, axis=1) / 2.0)
    huber = Huber(sig, huber_k)
    e_before = velocity_errors(data, b0, p0, g_free, b_lin)
    st = _solve(_Solve(b0, p0, g_free / g_norm, b_lin, data), huber,
                (b0, p0, g_free / g_norm), gravity, preint, max_iterations, on_iteration)
    marg = marginals(st.graph, st.sol)
    e_after = velocity_errors(st.data, st.b, st.p, gravity * st.g_dir, st.b_lin)
    w, chi2 = huber.weights_and_chi2(e_after)
    stats = StageStats(
        name="velocity", unit="m/s",
        rms_before=np.sqrt(np.mean(e_before**2, axis=0)).tolist(),
        rms_after=np.sqrt(np.mean(e_after**2, axis=0)).tolist(),
        n_factors=n, n_residuals=n, outliers=int(np.sum(w < 0.5)), iterations=st.iterations,
        seconds=time.perf_counter() - t0, chi2_per_dof=chi2 / max(1, 3 * n - 8),
        batch_evaluations=st.evaluations)
    series = ResidualSeries(0.5 * (s.tau[i0] + s.tau[i1]), e_before, e_after, w, "m/s")
    return VelocityResult(st.b, st.p, st.g_dir, g_norm,
                          np.asarray(marg.marginalCovariance(KEY_BA)),
                          np.asarray(marg.marginalCovariance(KEY_P)),
                          np.asarray(marg.marginalCovariance(KEY_G)), stats, series)


def _intervals(s: PreparedSession, delta: float, spacing: float,
               half: int) -> tuple[Array, Array, Array, Array]:
    """Marker velocity at every mocap sample, the usable keyframes and the intervals between
    them (start and end indices)."""
    _, vM, valid = local_derivative(s.tau, s.p_WM, half, s.gap)
    kf = keyframes(s.tau, spacing)
    kf = kf[valid[kf]]
    i0, i1 = kf[:-1], kf[1:]
    ok = (s.segments_without_gaps(i0, i1) & s.imu_covers(s.tau[i0], s.tau[i1], delta)
          # a keyframe dropped (invalid derivative) leaves a longer interval: keep it short
          & (s.tau[i1] - s.tau[i0] < 2.5 * spacing))
    i0, i1 = i0[ok], i1[ok]
    if len(i0) < 10:
        raise ObservabilityError(f"only {len(i0)} gap-free velocity intervals; "
                                 f"{s.gap_cause()}")
    return vM, kf, i0, i1


def _linear_start(data: _Data, gravity: float) -> tuple[Array, Array, Array, float]:
    """Linear initial guess of ``p_MI``, the free gravity vector and ``b_a`` (and ``|g|``)."""
    n = len(data.dt)
    M = np.zeros((n, 3, 9))
    M[:, :, 0:3] = data.LM
    M[:, :, 3:6] = -np.eye(3) * data.dt[:, None, None]
    M[:, :, 6:9] = data.R_i @ data.A
    rhs = -(data.dvM - np.einsum("nij,nj->ni", data.R_i, data.dv))
    # Solve around a level world (g along -z): directions the motion leaves undetermined (e.g.
    # accel bias along a body axis that stays vertical) keep that guess instead of blowing up.
    x0 = np.r_[np.zeros(3), 0.0, 0.0, -gravity, np.zeros(3)]
    Am = M.reshape(-1, 9)
    H = Am.T @ Am
    H_reg = H + 1e-9 * np.trace(H) / 9.0 * np.eye(9)
    x = x0 + np.linalg.solve(H_reg, Am.T @ (rhs.reshape(-1) - Am @ x0))
    p0, g_free, b0 = x[0:3], x[3:6], x[6:9]
    g_norm = float(np.linalg.norm(g_free))
    # Residual-scaled uncertainty of the free gravity vector: only check |g| where it is known.
    res = rhs.reshape(-1) - Am @ x
    s2 = float(res @ res) / max(1, Am.shape[0] - 9)
    g_sig = np.sqrt(np.diag(np.linalg.inv(H_reg))[3:6] * s2)
    if np.all(g_sig < 0.05 * gravity) and not 0.7 * gravity < g_norm < 1.3 * gravity:
        raise ObservabilityError(
            f"the accelerometer and mocap disagree on gravity (|g| fits as {g_norm:.2f} m/s^2, "
            f"expected {gravity:.2f}); check the accel units, the mocap units (m) and the time "
            "offset")
    return p0, g_free, b0, g_norm
