"""Kinematics of both streams on a common grid, for closed-form fits (conventions, degenerate
motion): the mocap's body rates, angular acceleration and acceleration from its poses, the IMU
box-averaged and smoothed the same way, and the best orthogonal map between the two rate
series (Kabsch with free scale and handedness).

Smoothing is linear and time-invariant, so it commutes with differentiation: the second
derivative of the smoothed mocap position is the smoothed acceleration, comparable with the
smoothed accelerometer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from mocap_calib.core.model import so3
from mocap_calib.core.prepare.noise_band import BRIDGE_S
from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]

#: Grid step (s) and smoothing (s, Gaussian sigma) of the closed-form fits.
GRID_S = 0.01
SMOOTH_S = 0.04
#: Longest stretch (s) the fits use (the middle of the overlap): enough, and fast.
STRETCH_S = 60.0


def smooth(x: Array, width: float = SMOOTH_S) -> Array:
    return gaussian_filter1d(x, width / GRID_S, axis=0, mode="nearest")


def smoothing_of(s: PreparedSession) -> float:
    """The session's smoothing (s): :data:`SMOOTH_S`, or wider when the mocap's noise needs
    it (``s.band_s``, chosen from the data when the session was prepared)."""
    return max(SMOOTH_S, s.band_s)


@dataclass(frozen=True)
class SmoothedImu:
    """The IMU box-averaged over a grid step (no aliasing when sampled on the grid)."""

    u: Array
    gyro: Array
    accel: Array
    session: PreparedSession | None = None
    width: float = SMOOTH_S

    @classmethod
    def of(cls, s: PreparedSession) -> SmoothedImu:
        n = max(1, int(round(GRID_S * s.imu_rate))) | 1  # odd: centred, no half-sample delay
        k = np.ones(n) / n
        box = [np.stack([np.convolve(x[:, i], k, mode="same") for i in range(3)], axis=1)
               for x in (s.gyro, s.accel)]
        return cls(s.u, box[0], box[1], s, smoothing_of(s))

    def clear(self, u: Array) -> NDArray[np.bool_]:
        """Points whose smoothed value reaches no IMU gap."""
        if self.session is None:
            return np.ones(len(u), bool)
        reach = 4 * self.width + GRID_S
        return self.session.imu_clear(u - reach, u + reach)

    def at(self, u: Array) -> tuple[Array, Array]:
        """Gyro and accelerometer smoothed at times ``u`` (smoothed on a contiguous grid, so
        that points left out of ``u`` do not change the filter)."""
        pad = 4 * self.width + GRID_S
        grid = np.arange(u.min() - pad, u.max() + pad + GRID_S, GRID_S)
        out = []
        for x in (self.gyro, self.accel):
            on = smooth(np.stack([np.interp(grid, self.u, x[:, i]) for i in range(3)], axis=1),
                        self.width)
            out.append(np.stack([np.interp(u, grid, on[:, i]) for i in range(3)], axis=1))
        return out[0], out[1]


@dataclass(frozen=True)
class MocapGrid:
    """One reading of the mocap on a grid (mocap clock): body rates, angular acceleration,
    acceleration, attitudes; ``ok`` marks the points away from gaps and ends."""

    T: Array
    ok: NDArray[np.bool_]
    w_M: Array
    alpha: Array
    a_W: Array
    R: Array


def mocap_grid(s: PreparedSession, R: Array, p: Array, lo: float, hi: float) -> MocapGrid:
    width = smoothing_of(s)
    T = np.arange(lo, hi, GRID_S)
    idx = np.clip(np.searchsorted(s.tau, T), 1, len(s.tau) - 1)
    # Holes the smoothing bridges (a radio link's dropouts) are not gaps.
    gap = (s.tau[idx] - s.tau[idx - 1]) > max(s.gap, BRIDGE_S)
    # Smoothing and differences reach a few sigma around a gap: leave those points out.
    reach = int(np.ceil(4 * width / GRID_S)) + 2
    bad = np.convolve(gap.astype(float), np.ones(2 * reach + 1), mode="same") > 0
    bad[:reach] = bad[-reach:] = True
    i = np.clip(idx - 1, 0, len(s.tau) - 2)
    a = np.clip((T - s.tau[i]) / (s.tau[i + 1] - s.tau[i]), 0.0, 1.0)
    d = so3.log(np.einsum("nji,njk->nik", R[i], R[i + 1]))
    Rg = R[i] @ so3.exp(a[:, None] * d)
    pg = p[i] + a[:, None] * (p[i + 1] - p[i])
    w_mid = so3.log(np.einsum("nji,njk->nik", Rg[:-1], Rg[1:])) / GRID_S
    w_M = smooth(np.vstack([w_mid[:1], 0.5 * (w_mid[1:] + w_mid[:-1]), w_mid[-1:]]), width)
    alpha = np.gradient(w_M, GRID_S, axis=0)
    a_W = np.gradient(np.gradient(smooth(pg, width), GRID_S, axis=0), GRID_S, axis=0)
    return MocapGrid(T, ~bad, w_M, alpha, a_W, Rg)


def overlap(s: PreparedSession, delta: float, margin: float) -> tuple[float, float] | None:
    """The middle (at most :data:`STRETCH_S`) of the streams' overlap at ``delta``."""
    lo = max(s.tau[0], s.u[0] + delta) + margin
    hi = min(s.tau[-1], s.u[-1] + delta) - margin
    if hi - lo < 5.0:
        return None
    mid = 0.5 * (lo + hi)
    return max(lo, mid - STRETCH_S / 2), min(hi, mid + STRETCH_S / 2)


def rotation_fit(g_I: Array, w_M: Array) -> tuple[float, bool, float, Array, Array]:
    """``w_M = scale Q (w_I - b)``, ``Q`` orthogonal (Kabsch, free scale and handedness).
    Returns (residual ratio, reflected, scale, Q, the centred mocap rates)."""
    a = g_I - g_I.mean(axis=0)
    b = w_M - w_M.mean(axis=0)
    U, S, Vt = np.linalg.svd(a.T @ b)
    det = float(np.sign(np.linalg.det(Vt.T @ U.T)))
    aa, bb = float(np.sum(a * a)), float(np.sum(b * b))
    proper = S[0] + S[1] + det * S[2]
    rot_res = bb - proper**2 / max(aa, 1e-300)  # best rotation
    orth_res = bb - S.sum() ** 2 / max(aa, 1e-300)  # best orthogonal map
    reflected = bool(det < 0 and orth_res < 0.25 * rot_res)
    Q = Vt.T @ U.T if reflected else Vt.T @ np.diag([1.0, 1.0, det]) @ U.T
    res = orth_res if reflected else rot_res
    scale = (S.sum() if reflected else proper) / max(aa, 1e-300)
    return float(np.sqrt(max(res, 0.0) / max(bb, 1e-300))), reflected, float(scale), Q, b
