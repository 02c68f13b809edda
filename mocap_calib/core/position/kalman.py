"""The window filter's parts: the mocap noise of a residual, the covariance prediction, the
likelihood-only pass and the accumulator of a full pass (see
:mod:`mocap_calib.core.position.engine`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.windows import EvalOut

Array = NDArray[np.float64]

#: Diffuse prior of a window's start state: attitude (rad), position (m), velocity (m/s).
DIFFUSE = (1.0, 1.0, 0.5)


def signals_at(gyro: Array, accel: Array, interp, x: Array,
                rates: bool) -> tuple[Array, Array, Array, Array | None, Array | None]:
    """Raw gyro and accel (and, with ``rates``, their time derivatives) through ``interp`` at
    times ``x``: the arguments of ``correct``."""
    return (interp(gyro), interp(accel), x, interp.derivative(gyro) if rates else None,
            interp.derivative(accel) if rates else None)


def step_mean(y_nodes: Array, hs: Array, h: Array) -> Array:
    """(W, m, c) mean over each step of a signal given at the pieces' nodes (Simpson per piece,
    exact for the cubic on each piece)."""
    simpson = (y_nodes[..., 0:-1:2, :] + 4.0 * y_nodes[..., 1::2, :] + y_nodes[..., 2::2, :]) / 6.0
    total = np.einsum("wmp,wmpc->wmc", hs, simpson)
    return total / np.where(h > 0, h, 1.0)[..., None]


def mocap_cov(L: Array, sr2: float, sp2: float) -> Array:
    """(..., 6, 6) covariance of a residual's mocap noise: attitude noise ``sr2`` per axis
    (I frame), position noise ``sp2``, and the position error ``-L`` times the attitude noise."""
    out = np.empty(L.shape[:-2] + (6, 6))
    Lt = np.swapaxes(L, -1, -2)
    out[..., 0:3, 0:3] = sr2 * np.eye(3)
    out[..., 0:3, 3:6] = -sr2 * Lt
    out[..., 3:6, 0:3] = -sr2 * L
    out[..., 3:6, 3:6] = sp2 * np.eye(3) + sr2 * L @ Lt
    return out


def predict_covariance(P: Array, Phi: Array, noise: Noise, k: int) -> Array:
    """Filter covariance through step ``k``: transition plus process noise."""
    P = Phi @ P @ np.swapaxes(Phi, 1, 2)
    i15, i3 = np.arange(15), np.arange(3)
    P[:, i15, i15] += noise.q_diag[:, k]
    P[:, 3 + i3, 6 + i3] += noise.q_pv[:, k, None]
    P[:, 6 + i3, 3 + i3] += noise.q_pv[:, k, None]
    if noise.Qm is not None:
        P[:, 15:, 15:] += noise.Qm[:, k]
    return P


def likelihood_pass(r: Array, Phi: Array, noise: Noise, wts: Array,
                     mask: NDArray[np.bool_]) -> Array:
    """(W,) chi2 and log det of the innovations of the residuals ``r`` alone (no Jacobian)."""
    W, m1 = mask.shape
    ns = Phi.shape[-1]
    corr = ns == 21
    P = np.zeros((W, ns, ns))
    for i, d in enumerate(DIFFUSE):
        P[:, 3 * i:3 * i + 3, 3 * i:3 * i + 3] = d**2 * np.eye(3)
    if corr:
        P[:, 15:, 15:] = noise.Pm0
    x = np.zeros((W, ns, 1))
    chi2 = np.zeros(W)
    logdet = np.zeros(W)
    for k in range(m1):
        if k > 0:
            x = Phi[:, k - 1] @ x
            P = predict_covariance(P, Phi[:, k - 1], noise, k - 1)
        e = r[:, k, :, None] - (x[:, 0:6] + x[:, 15:21] if corr else x[:, 0:6])
        PHt = P[:, :, 0:6] + P[:, :, 15:21] if corr else P[:, :, 0:6]
        HPHt = PHt[:, 0:6] + PHt[:, 15:21] if corr else PHt[:, 0:6]
        Lc = np.linalg.cholesky(HPHt + noise.Rn[:, k] / wts[:, k, None, None])
        z = np.linalg.solve(Lc, e)
        ok = mask[:, k]
        chi2 += np.where(ok, np.sum(z[..., 0] ** 2, axis=1), 0.0)
        logdet += np.where(ok, 2.0 * np.sum(np.log(np.diagonal(Lc, axis1=1, axis2=2)), axis=1),
                           0.0)
        K = np.linalg.solve(np.swapaxes(Lc, 1, 2), np.linalg.solve(Lc, np.swapaxes(PHt, 1, 2)))
        K = np.swapaxes(K, 1, 2)  # P H^T S^-1
        K[~ok] = 0.0
        x += K @ e
        P -= K @ np.swapaxes(PHt, 1, 2)
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
    return chi2, logdet


class Accumulator:
    """What a filter pass collects per sample and window (Gram matrix, innovations, scores).

    The pass only stores each sample's whitened rows; the sums come in :meth:`result`, as a
    few large products instead of a handful of small ones per sample (the pass's loop is the
    engine's cost)."""

    def __init__(self, W: int, m: int, p: int, store: bool,
                 blocks: NDArray[np.int64] | None) -> None:
        self.p = p
        self.store = store
        self.Nw = np.zeros((W, m + 1, 6, p + 1))
        self.innov = np.zeros((W, m + 1, 6))
        # The robust test's own innovation norm where a sample is down-weighted (NaN: the
        # whitened innovation's norm, filled in at the end).
        self.d_raw = np.full((W, m + 1), np.nan)
        self.logdet_k = np.zeros((W, m + 1))
        self.raw_J = np.zeros((W, m + 1, 6, p)) if store else None
        self.blocks = blocks

    def add(self, k: int, N: Array, Nw: Array, Li: Array, ok: NDArray[np.bool_]) -> None:
        self.Nw[:, k] = Nw
        self.innov[:, k] = N[:, :, self.p]
        self.logdet_k[:, k] = np.where(ok, 2.0 * np.sum(np.log(np.diagonal(Li, axis1=1, axis2=2)),
                                                        axis=1), 0.0)

    def result(self, mask: NDArray[np.bool_], raw_r: Array | None,
               extras: dict[str, Array]) -> EvalOut:
        p = self.p
        W, m1 = self.Nw.shape[:2]
        flat = self.Nw.reshape(W, m1 * 6, p + 1)
        gram = np.swapaxes(flat, 1, 2) @ flat
        e = self.Nw[..., p]  # (W, m+1, 6) whitened innovations
        e2 = e**2
        chi2 = e2.sum(axis=(1, 2))
        # Li is lower-triangular: the first three whitened components involve only the
        # attitude innovation and its own covariance block.
        q_rot = e2[..., 0:3].sum(axis=2)
        q_pos = e2[..., 3:6].sum(axis=2)
        d_raw = np.where(np.isnan(self.d_raw), np.sqrt(q_rot + q_pos), self.d_raw)
        d_raw[~mask] = 0.0
        self.innov[~mask] = 0.0
        scores = None
        if self.blocks is not None:
            per_sample = np.einsum("wkrp,wkr->wkp", self.Nw[..., :p], e)
            starts = np.flatnonzero(np.r_[True, np.diff(self.blocks) != 0])
            scores = np.add.reduceat(per_sample, starts, axis=1)
        return EvalOut(gram, self.innov, d_raw, chi2, q_rot, q_pos,
                       -self.logdet_k.sum(axis=1), scores, raw_r, self.raw_J,
                       self.Nw if self.store else None, extras)


@dataclass(frozen=True)
class Noise:
    q_diag: Array  # (W, m, 15) diagonal process noise per step
    q_pv: Array  # (W, m) position-velocity cross term
    Rn: Array  # (W, m+1, 6, 6) white mocap noise of each residual
    # Correlated mocap noise (states 15:21, in residual coordinates), when modelled:
    Fm: Array | None = None  # (W, m, 6, 6) its transition per step
    Qm: Array | None = None  # (W, m, 6, 6) its process noise per step
    Pm0: Array | None = None  # (W, 6, 6) its stationary covariance at the first sample


def filter_noise(nz: NoiseModel, L: Array, h: Array) -> Noise:
    """Process noise of every step and mocap noise of every sample, for windows with steps
    ``h`` (W, m) and lever-arm Jacobians ``L`` (W, m+1, 3, 3): d p_meas / d attitude noise.

    Mocap noise: per-sample attitude noise (marker frame) and position noise; the attitude
    noise also moves ``p_meas`` through the lever arm. A fraction of its variance is white,
    the rest an AR(1) process with time constant ``mocap_noise_corr_time``, carried as six
    filter states in residual coordinates (``m = H_k n``, so the measurement is simply
    state + state; ``H_k`` changes with the marker attitude, hence ``Fm``).
    """
    W, m = h.shape
    # Process noise per step (isotropic densities, so frame rotations drop out).
    sg2 = nz.gyroscope_noise_density**2
    sa2 = nz.accelerometer_noise_density**2
    q_diag = np.empty((W, m, 15))
    q_diag[..., 0:3] = (sg2 * h)[..., None]
    q_diag[..., 3:6] = (sa2 * h**3 / 3.0)[..., None]
    q_diag[..., 6:9] = (sa2 * h)[..., None]
    q_diag[..., 9:12] = (nz.gyroscope_random_walk**2 * h)[..., None]
    q_diag[..., 12:15] = (nz.accelerometer_random_walk**2 * h)[..., None]
    q_pv = sa2 * h**2 / 2.0
    full = mocap_cov(L, nz.mocap_rotation_sigma**2, nz.mocap_position_sigma**2)
    if not nz.mocap_correlated:
        return Noise(q_diag, q_pv, full)
    rho = nz.mocap_noise_corr_fraction
    a = np.exp(-h / nz.mocap_noise_corr_time)[..., None, None]  # (W, m, 1, 1)
    Fm = np.zeros((W, m, 6, 6))
    Fm[..., 0:3, 0:3] = np.eye(3)
    Fm[..., 3:6, 3:6] = np.eye(3)
    Fm[..., 3:6, 0:3] = L[:, :-1] - L[:, 1:]  # H_{k+1} H_k^-1
    Fm *= a
    Qm = rho * (1.0 - a * a) * full[:, 1:]
    return Noise(q_diag, q_pv, (1.0 - rho) * full, Fm, Qm, rho * full[:, 0])
