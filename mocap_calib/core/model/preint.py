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

from mocap_calib.core.jit import kernel
from mocap_calib.core.model import so3
from mocap_calib.core.threads import map_blocks

Array = NDArray[np.float64]

#: Fewest pieces in a block of :func:`integrate_pieces` on the threads.
MIN_BLOCK_PIECES = 16384


@dataclass(frozen=True)
class Interp:
    """Cubic Hermite (Catmull-Rom with non-uniform tangents) interpolation of samples at times
    ``t`` for query times ``u``: ``y(u) = sum_j weight_j(u) y[seg - 1 + j]`` and likewise
    ``dy/du``. The weights are computed where they are used (compiled), so an interpolant holds
    only its queries and their segments.
    """

    t: Array
    u: Array
    seg: NDArray[np.int64]  # first sample of each query's segment (clipped to [1, n - 3])

    def __call__(self, y: Array) -> Array:
        return self._eval(y, False)

    def derivative(self, y: Array) -> Array:
        return self._eval(y, True)

    def _eval(self, y: Array, deriv: bool) -> Array:
        y = np.ascontiguousarray(y, dtype=float)
        out = np.empty((self.u.size, y.shape[-1]))
        _hermite_kernel(self.t, self.u.reshape(-1), self.seg.reshape(-1), y, deriv, out)
        return out.reshape(self.u.shape + (y.shape[-1],))


def hermite(t: Array, u: Array) -> Interp:
    """Interpolation of samples at times ``t`` (sorted) for query times ``u``.

    Queries must lie within ``[t[1], t[-2]]``; outside it the end segment is extrapolated.
    """
    t = np.ascontiguousarray(t, dtype=float)
    u = np.ascontiguousarray(u, dtype=float)
    seg = np.clip(search_sorted(t, u, right=True) - 1, 1, len(t) - 3)
    return Interp(t, u, seg)


def search_sorted(t: Array, x: Array, right: bool = False) -> NDArray[np.int64]:
    """``np.searchsorted(t, x, side)`` (``t`` sorted) for queries that mostly ascend, as the
    nodes of consecutive windows do: each query's search starts from the previous answer and
    widens until it brackets its own (exponential search), so a sweep through the session costs
    about one comparison per query instead of a binary search of the whole session."""
    t = np.ascontiguousarray(t, dtype=float)
    xs = np.ascontiguousarray(x, dtype=float)
    out = np.empty(xs.shape, dtype=np.int64)
    _search_kernel(t, xs.reshape(-1), right, out.reshape(-1))
    return out


@kernel
def _search_kernel(t, x, right, out):  # pragma: no cover  (compiled)
    """``out[q]`` = the number of ``t`` below ``x[q]`` (with ``right``: at or below); NaN
    queries go to the end, as numpy puts them."""
    n = t.shape[0]
    j = 0
    for q in range(x.shape[0]):
        v = x[q]
        if v != v:
            out[q] = n
            continue
        # Bracket the answer r in [lo, hi]: t[i] is below v for every i < lo, and hi == n or
        # t[hi] is not.
        if j < n and (t[j] <= v if right else t[j] < v):
            lo, hi, step = j + 1, j + 1, 1
            while hi < n and (t[hi] <= v if right else t[hi] < v):
                lo = hi + 1
                hi = lo + step
                step *= 2
            hi = min(hi, n)
        else:
            lo, hi, step = j, j, 1
            while lo > 0 and not (t[lo - 1] <= v if right else t[lo - 1] < v):
                hi = lo - 1
                lo = hi - step
                step *= 2
            lo = max(lo, 0)
        while lo < hi:
            mid = (lo + hi) // 2
            if t[mid] <= v if right else t[mid] < v:
                lo = mid + 1
            else:
                hi = mid
        out[q] = lo
        j = lo


@kernel
def _hermite_kernel(t, u, seg, y, deriv, out):  # pragma: no cover  (compiled)
    """``out[q] = sum_j weight_j y[seg[q] - 1 + j]`` (or with the derivative's weights)."""
    nc = y.shape[1]
    for q in range(u.shape[0]):
        i = seg[q]
        t0, t1 = t[i], t[i + 1]
        d = t1 - t0
        s = (u[q] - t0) / d
        a1, a2 = d / (t1 - t[i - 1]), d / (t[i + 2] - t0)
        s2 = s * s
        s3 = s2 * s
        if deriv:
            h00, h10 = (6 * s2 - 6 * s) / d, (3 * s2 - 4 * s + 1) / d
            h01, h11 = (-6 * s2 + 6 * s) / d, (3 * s2 - 2 * s) / d
        else:
            h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        w0, w1, w2, w3 = -h10 * a1, h00 - h11 * a2, h01 + h10 * a1, h11 * a2
        for c in range(nc):
            out[q, c] = w0 * y[i - 1, c] + w1 * y[i, c] + w2 * y[i + 1, c] + w3 * y[i + 2, c]


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
    packed: Array | None = None  # (..., 51): dR, dv, dp, A, C, B, D flattened, one row a step

    def pack(self) -> Array:
        """(..., 51) all increments of a step in one row (the compiled filter's input)."""
        if self.packed is not None:
            return self.packed
        lead = self.dv.shape[:-1]
        return np.concatenate([x.reshape(lead + (-1,)) for x in
                               (self.dR, self.dv, self.dp, self.A, self.C, self.B, self.D)], -1)


def integrate_pieces(w_nodes: Array, f_nodes: Array, hs_all: Array) -> StepIncrements:
    """RK4-integrate each step piece by piece; piece ``i`` runs from node ``2i`` through its
    midpoint node ``2i + 1`` to node ``2i + 2`` (compiled: :func:`_integrate_kernel`).

    Args:
        w_nodes: (..., 2 n + 1, 3) angular rate at the nodes.
        f_nodes: (..., 2 n + 1, 3) specific force at the nodes.
        hs_all: (..., n) piece durations (zero-length pieces are allowed: padding).
    """
    lead = hs_all.shape[:-1]
    n_sub = hs_all.shape[-1]
    S = int(np.prod(lead, dtype=np.int64))
    w = np.ascontiguousarray(w_nodes, dtype=float).reshape(S, 2 * n_sub + 1, 3)
    f = np.ascontiguousarray(f_nodes, dtype=float).reshape(S, 2 * n_sub + 1, 3)
    hs = np.ascontiguousarray(hs_all, dtype=float).reshape(S, n_sub)
    out = np.empty((S, 51))
    # A session's steps at once (the first fits) in two blocks on the threads; the engine's
    # chunks already run there, one block each.
    per = -(-S // 2) if S * n_sub >= 2 * MIN_BLOCK_PIECES else max(S, 1)
    map_blocks(lambda a: _integrate_kernel(w[a:a + per], f[a:a + per], hs[a:a + per],
                                           out[a:a + per]), range(0, max(S, 1), per))
    m3 = lead + (3, 3)
    return StepIncrements(out[:, 0:9].reshape(m3), out[:, 9:12].reshape(lead + (3,)),
                          out[:, 12:15].reshape(lead + (3,)), out[:, 15:24].reshape(m3),
                          out[:, 24:33].reshape(m3), out[:, 33:42].reshape(m3),
                          out[:, 42:51].reshape(m3), out.reshape(lead + (51,)))


@kernel(inline=True)
def _rk_stage(y, w, f, s, node, k, st):  # pragma: no cover  (compiled)
    """Derivative ``k[st]`` of the state ``y`` = (q, v, p, A, C, B, D) flattened (46 values)
    at node ``node`` of step ``s`` (rates ``w[s, node]``, specific force ``f[s, node]``, read in
    place): ``q (0, w) / 2``, ``R f``, ``v``, ``R``, ``A``, ``[R f]x A``, ``B``."""
    w0, w1, w2 = w[s, node, 0], w[s, node, 1], w[s, node, 2]
    g0, g1, g2 = f[s, node, 0], f[s, node, 1], f[s, node, 2]
    n = np.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
    qw, qx, qy, qz = y[0] / n, y[1] / n, y[2] / n, y[3] / n
    R0, R1, R2 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
    R3, R4, R5 = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
    R6, R7, R8 = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
    f0, f1, f2 = R0 * g0 + R1 * g1 + R2 * g2, R3 * g0 + R4 * g1 + R5 * g2, \
        R6 * g0 + R7 * g1 + R8 * g2
    k[st, 0] = 0.5 * (-y[1] * w0 - y[2] * w1 - y[3] * w2)
    k[st, 1] = 0.5 * (y[0] * w0 + y[2] * w2 - y[3] * w1)
    k[st, 2] = 0.5 * (y[0] * w1 - y[1] * w2 + y[3] * w0)
    k[st, 3] = 0.5 * (y[0] * w2 + y[1] * w1 - y[2] * w0)
    k[st, 4], k[st, 5], k[st, 6] = f0, f1, f2
    for a in range(3):
        k[st, 7 + a] = y[4 + a]
    k[st, 10], k[st, 11], k[st, 12] = R0, R1, R2
    k[st, 13], k[st, 14], k[st, 15] = R3, R4, R5
    k[st, 16], k[st, 17], k[st, 18] = R6, R7, R8
    for a in range(9):
        k[st, 19 + a] = y[10 + a]  # dC = A
        k[st, 37 + a] = y[28 + a]  # dD = B
    for j in range(3):  # dB = [Rf]x A, column by column
        a0, a1, a2 = y[10 + j], y[13 + j], y[16 + j]
        k[st, 28 + j] = f1 * a2 - f2 * a1
        k[st, 31 + j] = f2 * a0 - f0 * a2
        k[st, 34 + j] = f0 * a1 - f1 * a0


@kernel
def _integrate_kernel(w, f, hs, out):  # pragma: no cover  (compiled)
    """RK4 over the pieces of every step; ``out`` columns: dR, dv, dp, A, C, B, D
    (flattened). Stage ``st`` is evaluated at the state plus ``c[st] h`` times the previous
    stage's derivative, at the piece's start, midpoint, midpoint and end node."""
    S, n_sub = hs.shape
    y, ys = np.empty(46), np.empty(46)
    k = np.empty((4, 46))
    c = (0.0, 0.5, 0.5, 1.0)
    at = (0, 1, 1, 2)
    k[:, :] = 0.0
    for s in range(S):
        y[:] = 0.0
        y[0] = 1.0
        for i in range(n_sub):
            h = hs[s, i]
            if h == 0.0:
                continue  # padding: the identity
            for st in range(4):
                if st == 0:
                    ys[:] = y
                else:
                    ch = c[st] * h
                    for a in range(46):
                        ys[a] = y[a] + ch * k[st - 1, a]
                node = 2 * i + at[st]
                _rk_stage(ys, w, f, s, node, k, st)
            h6 = h / 6.0
            for a in range(46):
                y[a] += h6 * (k[0, a] + 2.0 * k[1, a] + 2.0 * k[2, a] + k[3, a])
            n = np.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
            for a in range(4):
                y[a] /= n
        qw, qx, qy, qz = y[0], y[1], y[2], y[3]
        out[s, 0] = 1 - 2 * (qy * qy + qz * qz)
        out[s, 1] = 2 * (qx * qy - qw * qz)
        out[s, 2] = 2 * (qx * qz + qw * qy)
        out[s, 3] = 2 * (qx * qy + qw * qz)
        out[s, 4] = 1 - 2 * (qx * qx + qz * qz)
        out[s, 5] = 2 * (qy * qz - qw * qx)
        out[s, 6] = 2 * (qx * qz - qw * qy)
        out[s, 7] = 2 * (qy * qz + qw * qx)
        out[s, 8] = 1 - 2 * (qx * qx + qy * qy)
        for a in range(42):
            out[s, 9 + a] = y[4 + a]


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


#: Spans preintegrated at once: the signals at every piece's nodes are held only for these
#: (a 60-min session's 360 000 mocap steps in one go: ~200 MB of them).
SPAN_CHUNK = 20_000


def preintegrate_spans(u: Array, gyro: Array, accel: Array, tau0: Array, tau1: Array,
                       delta: float, correct_fn) -> StepIncrements:
    """Preintegrate the IMU over mocap-time spans ``[tau0, tau1]`` (one "step" each).

    Args:
        u, gyro, accel: raw IMU samples on the IMU clock.
        tau0, tau1: (n,) span ends on the mocap clock.
        delta: mocap time minus IMU time.
        correct_fn: ``(gyro, accel, u) -> (w, f)`` applying the measurement model backwards.
    """
    if len(tau0) > SPAN_CHUNK:  # spans are independent: chunks give the same numbers
        parts = [preintegrate_spans(u, gyro, accel, tau0[k:k + SPAN_CHUNK],
                                    tau1[k:k + SPAN_CHUNK], delta, correct_fn)
                 for k in range(0, len(tau0), SPAN_CHUNK)]
        return StepIncrements(*(np.concatenate([getattr(p, f) for p in parts])
                                for f in ("dR", "dv", "dp", "A", "C", "B", "D")))
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
        interp: Hermite interpolation of the IMU samples at the nodes (IMU clock).
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
    i0 = search_sorted(t, tau0, right=True)  # first sample strictly after tau0
    i1 = search_sorted(t, tau1)  # first sample at or after tau1
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
    _compose_kernel(np.ascontiguousarray(inc.dR, dtype=float),
                    np.ascontiguousarray(inc.dv, dtype=float),
                    np.ascontiguousarray(inc.dp, dtype=float), np.ascontiguousarray(h, dtype=float),
                    np.ascontiguousarray(R0, dtype=float), np.ascontiguousarray(p0, dtype=float),
                    np.ascontiguousarray(v0, dtype=float),
                    np.ascontiguousarray(g_W, dtype=float), R, p, v)
    return R, p, v


@kernel
def _compose_kernel(dR, dv, dp, h, R0, p0, v0, g, R, p, v):  # pragma: no cover  (compiled)
    S, m = h.shape
    for s in range(S):
        R[s, 0] = R0[s]
        p[s, 0] = p0[s]
        v[s, 0] = v0[s]
        for k in range(m):
            hk = h[s, k]
            for i in range(3):
                rdp = R[s, k, i, 0] * dp[s, k, 0] + R[s, k, i, 1] * dp[s, k, 1] \
                    + R[s, k, i, 2] * dp[s, k, 2]
                rdv = R[s, k, i, 0] * dv[s, k, 0] + R[s, k, i, 1] * dv[s, k, 1] \
                    + R[s, k, i, 2] * dv[s, k, 2]
                p[s, k + 1, i] = p[s, k, i] + v[s, k, i] * hk + 0.5 * g[i] * hk * hk + rdp
                v[s, k + 1, i] = v[s, k, i] + g[i] * hk + rdv
                for j in range(3):
                    R[s, k + 1, i, j] = (R[s, k, i, 0] * dR[s, k, 0, j]
                                         + R[s, k, i, 1] * dR[s, k, 1, j]
                                         + R[s, k, i, 2] * dR[s, k, 2, j])
