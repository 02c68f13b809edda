"""The two fits of the multi-position calibration: accelerometer (static intervals) and
gyroscope (rotations between them), with their covariances and optional priors."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from mocap_calib.core.intrinsics.multipos.params import LOWER
from mocap_calib.core.intrinsics.multipos.prior import MultiposPrior
from mocap_calib.core.model import so3
from mocap_calib.core.model.preint import quat_increments, quat_product, sample_nodes
from mocap_calib.errors import ConvergenceError

Array = NDArray[np.float64]


def prior_block(prior: MultiposPrior | None, name: str,
                entries: Sequence[int]) -> tuple[Array, Array, Array]:
    """(indices into this fit's parameter vector, values, sigmas) of the used prior rows."""
    if prior is None:
        return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0)
    v, s, used = prior.rows(name)
    idx, vals, sigs = [], [], []
    for k, flat in enumerate(entries):
        if used[flat]:
            idx.append(k)
            vals.append(v[flat])
            sigs.append(s[flat])
    return np.asarray(idx, dtype=int), np.asarray(vals), np.asarray(sigs)


def covariance(J: Array, chi2_red: float) -> tuple[Array, float]:
    """``(J^T J)^-1`` scaled by ``max(1, chi2_red)`` and the condition number of ``J^T J``
    with normalised columns (so units do not inflate it)."""
    JtJ = J.T @ J
    d = np.sqrt(np.clip(np.diag(JtJ), 1e-300, None))
    Jn = JtJ / np.outer(d, d)
    cond = float(np.linalg.cond(Jn))
    cov = np.linalg.pinv(Jn, rcond=1e-12) / np.outer(d, d)
    # The residuals are whitened by the measured noise: scale up (never down) by the residual
    # variance so that unmodelled errors widen the sigmas.
    return cov * max(1.0, chi2_red), cond


# --------------------------------------------------------------------------------------------
# Accelerometer
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class AccelFit:
    M: Array
    b: Array
    cov: Array  # (9, 9) of [M lower entries (LOWER order), b]
    chi2: float  # reduced
    dof: int
    rms: float
    condition: float
    ok: bool


def accel_unpack(p: Array) -> tuple[Array, Array]:
    M = np.zeros((3, 3))
    for k, (i, j) in enumerate(LOWER):
        M[i, j] = p[k]
    return M, p[6:9]


def accel_model(p: Array, means: Array, sig: Array, g: float) -> tuple[Array, Array]:
    """Whitened residuals ``(g^2 - |h|^2) / (2 g sigma)`` and their Jacobian."""
    M, b = accel_unpack(p)
    L = np.linalg.inv(M)
    h = (means - b) @ L.T
    r = (g * g - np.sum(h * h, axis=1)) / (2.0 * g * sig)
    v = h @ L  # v_k = h^T L[:, k]
    J = np.zeros((len(means), 9))
    for k, (i, j) in enumerate(LOWER):
        J[:, k] = v[:, i] * h[:, j]
    J[:, 6:9] = v
    J /= (g * sig)[:, None]
    return r, J


def _accel_prior(prior: MultiposPrior | None) -> tuple[Array, Array, Array]:
    im, vm, sm = prior_block(prior, "accel_matrix", [3 * i + j for i, j in LOWER])
    ib, vb, sb = prior_block(prior, "accel_bias", [0, 1, 2])
    return np.concatenate([im, ib + 6]), np.concatenate([vm, vb]), np.concatenate([sm, sb])


def accel_pack(M: Array, b: Array) -> Array:
    return np.concatenate([[M[i, j] for i, j in LOWER], b])


def fit_accel(means: Array, sig: Array, g: float, prior: MultiposPrior | None,
              start: AccelFit | None = None) -> AccelFit:
    """Fit ``M_a`` (lower-triangular) and ``b_a`` to interval means whose calibrated norm must
    be ``g``.

    Args:
        means: (n, 3) mean accel of each static interval.
        sig: (n,) 1-sigma of the norm of each mean.
        g: ``|g|``.
        prior: optional prior on ``accel_matrix`` and ``accel_bias``.
        start: an earlier fit to start from (default: identity, or the prior's values).
    """
    pi, pv, ps = _accel_prior(prior)
    p0 = np.array([1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    # Start from the prior where there is one: the problem is then closer to linear.
    p0[pi] = pv
    if start is not None:
        p0 = accel_pack(start.M, start.b)

    def fun(p: Array) -> Array:
        r, _ = accel_model(p, means, sig, g)
        return np.concatenate([r, (p[pi] - pv) / ps])

    def jac(p: Array) -> Array:
        _, J = accel_model(p, means, sig, g)
        Jp = np.zeros((len(pi), 9))
        Jp[np.arange(len(pi)), pi] = 1.0 / ps
        return np.vstack([J, Jp])

    m = len(means) + len(pi)
    res = least_squares(fun, p0, jac=jac, method="lm" if m >= 9 else "trf",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    M, b = accel_unpack(res.x)
    dof = m - 9
    chi2 = float(np.sum(res.fun**2)) / dof if dof > 0 else float("nan")
    cov, cond = covariance(jac(res.x), chi2 if dof > 0 else 1.0)
    h = (means - b) @ np.linalg.inv(M).T
    rms = float(np.sqrt(np.mean((np.linalg.norm(h, axis=1) - g) ** 2)))
    ok = bool(res.success) and np.all(np.isfinite(res.x)) and np.linalg.det(M) > 0.5
    return AccelFit(M, b, cov, chi2, dof, rms, cond, ok)


# --------------------------------------------------------------------------------------------
# Gyroscope
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GyroFit:
    M: Array
    cov: Array
    chi2: float
    rms: float
    condition: float


def fit_gyro(gyro_pad: Array, dt_pad: Array, u_start: Array, u_end: Array, sig: Array,
             offset: Array, prior: MultiposPrior | None, start: Array | None = None) -> GyroFit:
    """Fit ``M_g`` so that integrated rotations carry each start gravity direction to the end.

    Args:
        gyro_pad: (m, L+1, 3) raw gyro of each rotation, padded by repeating the last sample.
        dt_pad: (m, L) step lengths, 0 in the padding (so padded steps are the identity).
        u_start: (m, 3) calibrated gravity direction of the interval before each rotation.
        u_end: (m, 3) same for the interval after.
        sig: (m,) 1-sigma of each residual component (rad).
        offset: what is subtracted before ``M_g^-1`` (fixed): the gyro bias (3,), or per
            sample ``b_g + G f`` (m, L+1, 3) with the g-sensitivity.
        prior: optional prior on ``gyro_matrix``.
        start: ``M_g`` to start from (default: identity, or the prior's values).
    """
    pi, pv, ps = prior_block(prior, "gyro_matrix", list(range(9)))
    x0 = np.eye(3).ravel()
    x0[pi] = pv
    if start is not None:
        x0 = np.asarray(start, dtype=float).ravel().copy()
    raw = gyro_pad - offset

    def predicted(x: Array) -> Array:
        C = np.linalg.inv(x.reshape(3, 3))
        q = quat_product(quat_increments(sample_nodes(raw @ C.T), dt_pad))
        R = so3.quat_to_rotmat(q)
        # R_WI(end) = R_WI(start) dR, so the body gravity direction moves as dR^T u.
        return np.einsum("mji,mj->mi", R, u_start)

    def fun(x: Array) -> Array:
        r = ((predicted(x) - u_end) / sig[:, None]).ravel()
        return np.concatenate([r, (x[pi] - pv) / ps])

    res = least_squares(fun, x0, method="lm", x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        diff_step=1e-7, max_nfev=400)
    x = res.x
    if not res.success or not np.all(np.isfinite(x)):
        raise ConvergenceError("multipos: the gyroscope fit did not converge; check that the "
                               "rotations between static orientations are in the log without "
                               "gaps and below the gyro's range")
    # Central differences at the optimum for the covariance (LM's returned Jacobian is the
    # forward-difference one of its last step).
    eps = 1e-6
    J = np.empty((len(res.fun), 9))
    for k in range(9):
        d = np.zeros(9)
        d[k] = eps
        J[:, k] = (fun(x + d) - fun(x - d)) / (2 * eps)
    # Each rotation gives 3 residual components but only 2 independent ones (unit vectors).
    n_data = 3 * len(u_start)
    dof = 2 * len(u_start) + len(pi) - 9
    rss = 2.0 / 3.0 * float(np.sum(res.fun[:n_data] ** 2)) + float(np.sum(res.fun[n_data:] ** 2))
    chi2 = rss / dof if dof > 0 else float("nan")
    cov, cond = covariance(J, chi2 if dof > 0 else 1.0)
    err = np.linalg.norm(predicted(x) - u_end, axis=1)
    return GyroFit(x.reshape(3, 3), cov, chi2, float(np.sqrt(np.mean(err**2))), cond)
