"""IMU signal interpolation and per-step preintegration with bias Jacobians (vectorised).

Between two mocap samples the IMU signal is the cubic Hermite interpolant of its samples (on the
IMU clock shifted by the time offset). Each step is cut at the IMU sample times inside it
(:func:`pieces`) and every piece is integrated by classical RK4 from its ends and midpoint
(:func:`integrate_pieces`). Alongside the increments ``dR, dv, dp`` (in the step-start body
frame) RK4 integrates the integrals that make up the exact error-state transition of the step:

    A = int dR dt,   C = int A dt,   B = int [dR f]x A dt,   D = int B dt.

All arrays carry arbitrary leading axes (windows x steps), so a whole session is integrated with
a handful of numpy calls.

Attitude only (the mocap-free tools: multi-position gyro fit, attitude-drift check): the
rotation ODE ``q' = 1/2 q (0, w)`` is linear and acts by right multiplication, so the RK4 step of
:func:`integrate_pieces` is ``q_k`` times an increment that does not depend on ``q_k``
(:func:`quat_increments`, the same nodes: piece ends and midpoint). All increments are then
computed at once and the attitude is their ordered product (:func:`quat_product`,
:func:`quat_cumprod`); :func:`sample_nodes` builds the nodes from samples with the rate linearly
interpolated between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Interp:
    """Cubic Hermite (Catmull-Rom with non-uniform tangents) interpolation weights.

    ``y(u) = sum_j weight[..., j] * y[index[..., j]]`` and likewise ``dy/du`` with ``dweight``.
    """

    index: NDArray[np.int64]
    weight: Array
    dweight: Array

    def __call__(self, y: Array) -> Array:
        return np.einsum("...j,...jc->...c", self.weight, y[self.index])

    def derivative(self, y: Array) -> Array:
        return np.einsum("...j,...jc->...c", self.dweight, y[self.index])


def hermite(t: Array, u: Array) -> Interp:
    """Interpolation weights of samples at times ``t`` (sorted) for query times ``u``.

    Queries must lie within ``[t[1], t[-2]]``; outside it the end segment is extrapolated.
    """
    n = len(t)
    i = np.clip(np.searchsorted(t, u, side="right") - 1, 1, n - 3)
    t0, t1 = t[i], t[i + 1]
    d = t1 - t0
    s = (u - t0) / d
    d1 = t1 - t[i - 1]
    d2 = t[i + 2] - t0
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    g00, g10, g01, g11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
    a1, a2 = d / d1, d / d2
    weight = np.stack([-h10 * a1, h00 - h11 * a2, h01 + h10 * a1, h11 * a2], axis=-1)
    dweight = np.stack([-g10 * a1, g00 - g11 * a2, g01 + g10 * a1, g11 * a2], axis=-1)
    dweight /= d[..., None]
    index = i[..., None] + np.arange(-1, 3)
    return Interp(index, weight, dweight)




@dataclass(frozen=True)
class StepIncrements:
    """Preintegrated quantities of each step, in the step-start body frame.

    Attributes:
        dR: (..., 3, 3) rotation increment.
        dv, dp: (..., 3) velocity / position increments (gravity excluded).
        A, C, B, D: (..., 3, 3) transition integrals (see module docstring).
    """

    dR: Array
    dv: Array
    dp: Array
    A: Array
    C: Array
    B: Array
    D: Array


def _qmul_vec(q: Array, w: Array) -> Array:
    """``0.5 * q (x) [0, w]`` for quaternion derivative."""
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    return 0.5 * np.stack([
        -qx * wx - qy * wy - qz * wz,
        qw * wx + qy * wz - qz * wy,
        qw * wy - qx * wz + qz * wx,
        qw * wz + qx * wy - qy * wx,
    ], axis=-1)


def _qrot(q: Array) -> Array:
    """Rotation matrix of a (not necessarily unit) quaternion."""
    n2 = np.einsum("...i,...i->...", q, q)
    return so3.quat_to_rotmat(q / np.sqrt(n2)[..., None])




def integrate_pieces(w_nodes: Array, f_nodes: Array, hs_all: Array) -> StepIncrements:
    """RK4-integrate each step piece by piece; piece ``i`` runs from node ``2i`` through its
    midpoint node ``2i + 1`` to node ``2i + 2``.

    Args:
        w_nodes: (..., 2 n + 1, 3) angular rate at the nodes.
        f_nodes: (..., 2 n + 1, 3) specific force at the nodes.
        hs_all: (..., n) piece durations (zero-length pieces are allowed: padding).
    """
    n_sub = hs_all.shape[-1]
    lead = hs_all.shape[:-1]
    q = np.zeros(lead + (4,))
    q[..., 0] = 1.0
    v = np.zeros(lead + (3,))
    p = np.zeros(lead + (3,))
    A = np.zeros(lead + (3, 3))
    C = np.zeros(lead + (3, 3))
    B = np.zeros(lead + (3, 3))
    D = np.zeros(lead + (3, 3))

    def deriv(qq: Array, vv: Array, AA: Array, BB: Array, w: Array, f: Array):
        R = _qrot(qq)
        Rf = np.einsum("...ij,...j->...i", R, f)
        return _qmul_vec(qq, w), Rf, vv, R, AA, so3.hat(Rf) @ AA, BB

    for i in range(n_sub):
        hs = hs_all[..., i, None]
        hs2 = hs[..., None]
        w0, wm, w1 = (w_nodes[..., 2 * i + j, :] for j in range(3))
        f0, fm, f1 = (f_nodes[..., 2 * i + j, :] for j in range(3))
        k1 = deriv(q, v, A, B, w0, f0)
        s2 = (q + 0.5 * hs * k1[0], v + 0.5 * hs * k1[1], A + 0.5 * hs2 * k1[3],
              B + 0.5 * hs2 * k1[5])
        k2 = deriv(*s2, wm, fm)
        s3 = (q + 0.5 * hs * k2[0], v + 0.5 * hs * k2[1], A + 0.5 * hs2 * k2[3],
              B + 0.5 * hs2 * k2[5])
        k3 = deriv(*s3, wm, fm)
        s4 = (q + hs * k3[0], v + hs * k3[1], A + hs2 * k3[3], B + hs2 * k3[5])
        k4 = deriv(*s4, w1, f1)

        def comb(idx: int, hh: Array, k1=k1, k2=k2, k3=k3, k4=k4) -> Array:
            return hh / 6.0 * (k1[idx] + 2 * k2[idx] + 2 * k3[idx] + k4[idx])

        q = q + comb(0, hs)
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        v = v + comb(1, hs)
        p = p + comb(2, hs)
        A = A + comb(3, hs2)
        C = C + comb(4, hs2)
        B = B + comb(5, hs2)
        D = D + comb(6, hs2)
    return StepIncrements(so3.quat_to_rotmat(q), v, p, A, C, B, D)


_IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


def _pure(v: Array) -> Array:
    return np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)


def sample_nodes(omega: Array) -> Array:
    """Nodes of :func:`quat_increments` from samples: the samples at the piece ends and the
    average of neighbours at the midpoints (the rate linearly interpolated, as imu_tk).

    Args:
        omega: (..., n, 3) rates at the sample times.

    Returns:
        (..., 2 n - 1, 3) nodes.
    """
    n = omega.shape[-2]
    nodes = np.empty(omega.shape[:-2] + (2 * n - 1, 3))
    nodes[..., 0::2, :] = omega
    nodes[..., 1::2, :] = 0.5 * (omega[..., :-1, :] + omega[..., 1:, :])
    return nodes


def quat_increments(w_nodes: Array, hs: Array) -> Array:
    """Quaternion increments ``p_i`` of one RK4 step per piece, ``q_{i+1} = q_i * p_i``.

    The rotation part of :func:`integrate_pieces` in closed form: piece ``i`` runs from node
    ``2i`` through its midpoint node ``2i + 1`` to node ``2i + 2``.

    Args:
        w_nodes: (..., 2 n + 1, 3) body rates at the nodes, rad/s.
        hs: (..., n) piece durations, s (zero: identity, for padding).

    Returns:
        (..., n, 4) increments ``[w, x, y, z]`` (unit norm up to O(h^5)).
    """
    w1 = w_nodes[..., 0:-1:2, :]
    w2 = w_nodes[..., 1::2, :]
    w3 = w_nodes[..., 2::2, :]
    h = np.asarray(hs, dtype=float)[..., None]
    one = np.zeros(w1.shape[:-1] + (4,))
    one[..., 0] = 1.0
    a1 = 0.5 * _pure(w1)
    a2 = 0.5 * so3.quat_multiply(one + 0.5 * h * a1, _pure(w2))
    a3 = 0.5 * so3.quat_multiply(one + 0.5 * h * a2, _pure(w2))
    a4 = 0.5 * so3.quat_multiply(one + h * a3, _pure(w3))
    return one + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)


def quat_product(p: Array) -> Array:
    """Ordered product ``p_0 * p_1 * ... * p_{n-1}`` along axis -2 (pairwise tree, normalised).

    Args:
        p: (..., n, 4) quaternions; identity entries can pad sequences of unequal length.

    Returns:
        (..., 4) unit quaternions.
    """
    p = np.asarray(p, dtype=float)
    if p.shape[-2] == 0:
        return np.broadcast_to(_IDENTITY_Q, p.shape[:-2] + (4,)).copy()
    while p.shape[-2] > 1:
        if p.shape[-2] % 2:
            pad = np.broadcast_to(_IDENTITY_Q, p.shape[:-2] + (1, 4))
            p = np.concatenate([p, pad], axis=-2)
        p = so3.quat_multiply(p[..., 0::2, :], p[..., 1::2, :])
    q = p[..., 0, :]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_cumprod(p: Array) -> Array:
    """Inclusive ordered prefix products ``p_0 * ... * p_i`` (Hillis-Steele scan, normalised).

    Args:
        p: (n, 4) quaternions.

    Returns:
        (n, 4) unit quaternions.
    """
    out = np.array(p, dtype=float, copy=True)
    d = 1
    while d < len(out):
        out[d:] = so3.quat_multiply(out[:-d], out[d:])
        d *= 2
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def preintegrate_spans(u: Array, gyro: Array, accel: Array, tau0: Array, tau1: Array,
                       delta: float, correct_fn) -> StepIncrements:
    """Preintegrate the IMU over mocap-time spans ``[tau0, tau1]`` (one "step" each).

    Args:
        u, gyro, accel: raw IMU samples on the IMU clock.
        tau0, tau1: (n,) span ends on the mocap clock.
        delta: mocap time minus IMU time.
        correct_fn: ``(gyro, accel, u) -> (w, f)`` applying the measurement model backwards.
    """
    pc = pieces(u, tau0, tau1, delta)
    w, f = correct_fn(pc(gyro), pc(accel), pc.nodes - delta)
    return integrate_pieces(w, f, pc.hs)


@dataclass(frozen=True)
class Pieces:
    """Each step cut at the IMU sample times inside it.

    Every piece lies between two consecutive IMU samples, where the cubic Hermite interpolant
    is one cubic, and RK4 on it (Simpson's rule at the piece's ends and midpoint) integrates it
    exactly. So every interior sample carries the same weight whatever the sub-sample phase of
    the clock offset and the cost is smooth in the offset. (Nodes spaced evenly within a mocap
    step sample the interpolant across sample boundaries; with vibration in a real IMU signal
    that makes the cost ripple with the IMU period and traps the offset in local minima.)

    Attributes:
        nodes: (..., 2 n + 1) times (mocap clock): piece ends and midpoints.
        hs: (..., n) piece durations (zero for padding).
        interp: Hermite weights of the IMU samples at the nodes (IMU clock).
    """

    nodes: Array
    hs: Array
    interp: Interp

    def __call__(self, y: Array) -> Array:
        """Signal ``y`` (IMU samples, (N, c)) at the nodes."""
        return self.interp(y)

    def derivative(self, y: Array) -> Array:
        """Time derivative of the interpolated signal at the nodes."""
        return self.interp.derivative(y)


def pieces(u: Array, tau0: Array, tau1: Array, delta: float) -> Pieces:
    """Cut steps ``[tau0, tau1]`` (mocap clock) at the IMU sample times ``u + delta``.

    Steps must lie within the IMU span. Steps with fewer samples inside are padded with
    zero-length pieces at their end, so all steps have the same number of pieces.
    """
    t = u + delta
    i0 = np.searchsorted(t, tau0, side="right")  # first sample strictly after tau0
    i1 = np.searchsorted(t, tau1, side="left")  # first sample at or after tau1
    count = np.maximum(i1 - i0, 0)
    n_in = int(count.max()) if count.size else 0
    j = np.arange(n_in)
    inner_idx = np.minimum(i0[..., None] + j, len(t) - 1)
    inner = np.where(j < count[..., None], t[inner_idx], tau1[..., None])
    bounds = np.concatenate([tau0[..., None], inner, tau1[..., None]], axis=-1)
    hs = np.diff(bounds, axis=-1)
    n = hs.shape[-1]
    nodes = np.empty(bounds.shape[:-1] + (2 * n + 1,))
    nodes[..., 0::2] = bounds
    nodes[..., 1::2] = 0.5 * (bounds[..., :-1] + bounds[..., 1:])
    # Nodes exactly on a sample must use the segment that starts there (the interpolant is
    # continuous, but its cubic differs on each side only in derivatives).
    return Pieces(nodes, hs, hermite(u, nodes - delta))


def compose(inc: StepIncrements, h: Array, R0: Array, p0: Array, v0: Array,
            g_W: Array) -> tuple[Array, Array, Array]:
    """Chain step increments from a start state into attitudes, positions and velocities.

    Args:
        inc: increments of ``m`` steps for ``S`` sequences (``dR``, ``dv``, ``dp`` of shape
            (S, m, ...)).
        h: (S, m) step lengths (s); R0, p0, v0: (S, 3, 3), (S, 3), (S, 3) start state.
        g_W: (3,) gravity in the world frame.

    Returns:
        R (S, m+1, 3, 3), p (S, m+1, 3), v (S, m+1, 3).
    """
    S, m = h.shape
    R = np.empty((S, m + 1, 3, 3))
    p = np.empty((S, m + 1, 3))
    v = np.empty((S, m + 1, 3))
    R[:, 0], p[:, 0], v[:, 0] = R0, p0, v0
    for k in range(m):
        hk = h[:, k, None]
        Rk = R[:, k]
        p[:, k + 1] = (p[:, k] + v[:, k] * hk + 0.5 * g_W * hk**2
                       + np.einsum("sij,sj->si", Rk, inc.dp[:, k]))
        v[:, k + 1] = v[:, k] + g_W * hk + np.einsum("sij,sj->si", Rk, inc.dv[:, k])
        R[:, k + 1] = Rk @ inc.dR[:, k]
    return R, p, v
