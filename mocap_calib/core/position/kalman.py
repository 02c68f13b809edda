"""The window filter's Python side: its noise parameters, the pass over a chunk of windows (the
loops are compiled: :mod:`mocap_calib.core.position.kernels`), the likelihood-only pass and the
state-space model written out (see :mod:`mocap_calib.core.position.engine`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.jit import kernel
from mocap_calib.core.model.so3_compiled import rot_log
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position import kernels as kn
from mocap_calib.core.position.kernels import (
    DIFFUSE,  # noqa: F401  (re-exported)
    Q_ACCEL,
    Q_ACCEL_WALK,
    Q_GYRO,
    Q_GYRO_WALK,
    RHO,
    T_CORR,
    accel_noise,
    lever,
    mocap_cov,
    step_lever,
    transition_blocks,
)
from mocap_calib.core.position.windows import EvalOut

Array = NDArray[np.float64]

#: Per-axis mocap variance multipliers that leave the noise model as it is.
UNIT_AXES = np.ones(6)


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


def noise_params(nz: NoiseModel, axis_scale: Array = UNIT_AXES) -> Array:
    """The filter's noise parameters (:data:`~mocap_calib.core.position.kernels.N_PAR` values):
    IMU densities and random walks squared, the correlated fraction and time constant of the
    mocap noise (zero when white), the six mocap variances: attitude per axis in the IMU
    frame, position per axis in the world frame, each times ``axis_scale``, and the
    accelerometer's variance factors per IMU axis."""
    par = np.zeros(kn.N_PAR)
    par[kn.Q_GYRO] = nz.gyroscope_noise_density**2
    par[kn.Q_ACCEL] = nz.accelerometer_noise_density**2
    par[kn.Q_GYRO_WALK] = nz.gyroscope_random_walk**2
    par[kn.Q_ACCEL_WALK] = nz.accelerometer_random_walk**2
    if nz.mocap_correlated:
        par[kn.RHO] = nz.mocap_noise_corr_fraction
        par[kn.T_CORR] = nz.mocap_noise_corr_time
    scale = np.asarray(axis_scale, dtype=float)
    par[kn.SIG2:kn.SIG2 + 3] = nz.mocap_rotation_sigma**2 * scale[0:3]
    par[kn.SIG2 + 3:kn.SIG2 + 6] = nz.mocap_position_sigma**2 * scale[3:6]
    par[kn.ACCEL_AXES:kn.ACCEL_AXES + 3] = nz.accelerometer_axis_scale
    return par


def lever_matrix(R_MI: Array, p_MI: Array) -> Array:
    """``[R_MI^T p_MI]x``: the position residual's rows on the attitude error are the nominal
    IMU attitude times it."""
    x, y, z = np.asarray(R_MI, dtype=float).T @ np.asarray(p_MI, dtype=float)
    return np.ascontiguousarray(np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]))


@dataclass(frozen=True)
class Whitening:
    """What the filter of a chunk of windows is made of, apart from the residuals: the steps'
    increments and the nominal start attitudes (the transitions; the kernel chains the
    attitudes as ``compose`` does), the noise parameters, the lever-arm matrix and the robust
    weights. A frozen whitening keeps the one of its recording: 51 numbers a step (single
    precision)."""

    inc: Array  # (W, m, 51) packed step increments
    R0: Array  # (W, 3, 3) nominal attitude at each window's start
    par: Array  # (N_PAR,) noise parameters
    M: Array  # (3, 3) lever-arm matrix [R_MI^T p_MI]x
    weights: Array  # (W, m+1) robust weights


@dataclass(frozen=True)
class Rows:
    """A chunk's residuals and the parts of their Jacobians not through the sensitivities."""

    r: Array  # (W, m+1, 6)
    Jinv: Array  # (W, m+1, 3, 3)
    Pm_rot: Array  # (W, m+1, 3, 3)
    Jp: Array  # (W, m+1, 3, 3) d r_pos / d p_MI: R_bar R_MI^T
    Hq: Array  # (W, m+1, 3, 3) R_bar [R_MI^T p_MI]x: d r_pos / d (nominal attitude, R_MI)
    R_WM0: Array  # (W, 3, 3) each window's first mocap attitude (the start pose's p_MI term)


def _c(x: Array) -> Array:
    return np.ascontiguousarray(x, dtype=float)


def empty_output(W: int, m1: int, p: int, n_blocks: int | None, store: bool,
                 integral: bool = False) -> EvalOut:
    """Zeroed outputs of a filter pass over ``W`` windows (chunks write their slices); with
    ``integral`` the windows' bias integrals too."""
    return EvalOut(np.zeros((W, p + 1, p + 1)), np.zeros((W, m1, 6)), np.zeros((W, m1)),
                   np.zeros(W), np.zeros(W), np.zeros((W, m1, 6)),
                   None if n_blocks is None else np.zeros((W, n_blocks, p)),
                   np.zeros((W, m1, 6)) if store else None,
                   np.zeros((W, m1, 6, p)) if store else None,
                   np.zeros((W, m1, 6, p + 1)) if store else None,
                   term_X=np.zeros((W, 6, p + 1)), term_P=np.zeros((W, 6, 6)),
                   int_X=np.zeros((W, 6, p + 1)) if integral else None,
                   int_P=np.zeros((W, 6, 12)) if integral else None)


def output_slice(out: EvalOut, sl: slice) -> EvalOut:
    """The windows ``sl`` of ``out`` (views: writing them writes ``out``)."""
    def cut(x: Array | None) -> Array | None:
        return None if x is None else x[sl]
    return EvalOut(out.gram[sl], out.innovation[sl], out.d_raw[sl], out.chi2[sl],
                   out.logdet[sl], out.e_white[sl], cut(out.scores), cut(out.raw_r),
                   cut(out.raw_J), cut(out.whitened), term_X=cut(out.term_X),
                   term_P=cut(out.term_P), int_X=cut(out.int_X), int_P=cut(out.int_P))


def filter_pass(h: Array, mask: NDArray[np.bool_], current: Whitening, Rbar: Array,
                op: Whitening | None, rows: Rows, dwf: Array, dg: Array, gcols: list[int],
                rs: int, ts: int, blocks: NDArray[np.int64] | None, out: EvalOut) -> None:
    """One filter pass over a chunk of windows, into ``out`` (zeroed, the chunk's windows):
    ``current`` and the nominal attitudes ``Rbar`` give the sensitivities' transitions (and,
    without ``op``, the whitening); ``op`` is a frozen whitening to reuse."""
    W = mask.shape[0]
    p = dwf.shape[-1]
    frozen = op is not None
    op = current if op is None else op
    store = out.raw_J is not None
    kn.filter_windows(
        _c(h), np.ascontiguousarray(mask), _c(current.weights), _c(current.inc), _c(Rbar),
        _c(op.inc), _c(op.R0), _c(op.weights), frozen, _c(dwf), _c(dg),
        np.asarray(gcols, dtype=np.int64), _c(rows.r), _c(rows.Jinv), _c(rows.Pm_rot),
        _c(rows.Jp), _c(rows.Hq), _c(rows.R_WM0), _c(op.M), _c(op.par), rs, ts,
        np.zeros(mask.shape[1], np.int64) if blocks is None else blocks,
        out.gram, out.innovation, out.e_white, out.d_raw, out.logdet,
        np.zeros((W, 0, p)) if out.scores is None else out.scores,
        out.raw_J if store else np.zeros((0, 0, 6, p)),
        out.whitened if store else np.zeros((0, 0, 6, p + 1)),
        out.term_X if out.term_X is not None else np.zeros((0, 6, p + 1)),
        out.term_P if out.term_P is not None else np.zeros((0, 6, 6)),
        out.int_X if out.int_X is not None else np.zeros((0, 6, p + 1)),
        out.int_P if out.int_P is not None else np.zeros((0, 6, 12)))
    out.chi2[:] = np.einsum("wki,wki->w", out.e_white, out.e_white)
    if store:
        out.raw_r[:] = rows.r
        out.extras.update(state_space(h, current, Rbar))


def likelihood_pass(h: Array, mask: NDArray[np.bool_], wh: Whitening, Rbar: Array,
                    r: Array) -> tuple[Array, Array]:
    """(W,) chi2 and log det of the innovations of the residuals ``r`` alone (the filter pass
    without Jacobian columns)."""
    W, m1 = mask.shape
    none = np.zeros((W, m1 - 1, 6, 0))
    # No Jacobian columns: the Jacobian parts are not read.
    rows = Rows(r, Rbar, Rbar, Rbar, Rbar, Rbar[:, 0])
    out = empty_output(W, m1, 0, None, False)
    filter_pass(h, mask, wh, Rbar, None, rows, none, np.zeros((3, 0)), [], -1, -1, None, out)
    return out.chi2, out.logdet


def state_space(h: Array, wh: Whitening, Rbar: Array) -> dict[str, Array]:
    """The filter's state-space model written out (tests against a dense likelihood):
    transitions ``F``, process noise ``Q``, white mocap noise ``Rn``, the
    position rows' attitude block ``Hp``, the weights, and with correlated mocap noise its
    ``Fm``, ``Qm`` and ``Pm0``."""
    W, m = h.shape
    corr = wh.par[kn.RHO] > 0 and wh.par[kn.T_CORR] > 0
    F, Q = np.zeros((W, m, 15, 15)), np.zeros((W, m, 15, 15))
    Rn, Hp = np.zeros((W, m + 1, 6, 6)), np.zeros((W, m + 1, 3, 3))
    Fm, Qm, Pm0 = np.zeros((W, m, 6, 6)), np.zeros((W, m, 6, 6)), np.zeros((W, 6, 6))
    state_space_kernel(_c(wh.inc), _c(Rbar), _c(h), _c(wh.M), _c(wh.par), F, Q, Rn, Hp, Fm, Qm,
                   Pm0)
    out = {"F": F, "Q": Q, "Rn": Rn, "Hp": Hp, "Rbar": Rbar.copy(), "h": h.copy(),
           "weights": wh.weights.copy()}
    if corr:
        out.update(Fm=Fm, Qm=Qm, Pm0=Pm0)
    return out


@kernel
def state_space_kernel(inc, Rbar, h, M, par, F, Q, Rn, Hp, Fm, Qm,
                Pm0):  # pragma: no cover  (compiled)
    """The window filter's state-space model written out (for checks against a dense
    likelihood): transitions, process noise, white mocap noise, the position rows' attitude
    block ``Hp`` and the AR(1) states' model."""
    W, m = h.shape
    ns = 21 if (par[RHO] > 0.0 and par[T_CORR] > 0.0) else 15
    Fb = np.zeros((8, 3, 3))
    Lk, Qa = np.zeros((3, 3)), np.zeros((3, 3))
    for w in range(W):
        lever(Rbar[w, 0], M, Lk)
        Hp[w, 0] = Lk
        mocap_cov(par, 1.0 - par[RHO] if ns == 21 else 1.0, Rn[w, 0])
        if ns == 21:
            mocap_cov(par, par[RHO], Pm0[w])
        for j in range(m):
            hk = h[w, j]
            a = step_lever(Rbar[w, j + 1], M, Lk, hk, ns, par)
            Hp[w, j + 1] = Lk
            transition_blocks(inc, w, j, Rbar[w, j], Fb)
            F[w, j] = 0.0
            for i in range(15):
                F[w, j, i, i] = 1.0
            for i in range(3):
                F[w, j, 3 + i, 6 + i] = hk
                for t in range(3):
                    for b, (r0, c0) in enumerate(((0, 0), (0, 9), (3, 0), (3, 9), (3, 12),
                                                  (6, 0), (6, 9), (6, 12))):
                        F[w, j, r0 + i, c0 + t] = Fb[b, i, t]
            Q[w, j] = 0.0
            if not accel_noise(par, Rbar[w, j], Qa):
                for i in range(3):
                    for t in range(3):
                        Qa[i, t] = par[Q_ACCEL] if i == t else 0.0
            for i in range(3):
                Q[w, j, i, i] = par[Q_GYRO] * hk
                Q[w, j, 9 + i, 9 + i] = par[Q_GYRO_WALK] * hk
                Q[w, j, 12 + i, 12 + i] = par[Q_ACCEL_WALK] * hk
                for t in range(3):
                    Q[w, j, 3 + i, 3 + t] = Qa[i, t] * hk ** 3 / 3.0
                    Q[w, j, 6 + i, 6 + t] = Qa[i, t] * hk
                    Q[w, j, 3 + i, 6 + t] = Qa[i, t] * hk ** 2 / 2.0
                    Q[w, j, 6 + i, 3 + t] = Qa[i, t] * hk ** 2 / 2.0
            mocap_cov(par, 1.0 - par[RHO] if ns == 21 else 1.0, Rn[w, j + 1])
            if ns == 21:
                Fm[w, j] = 0.0
                for i in range(6):
                    Fm[w, j, i, i] = a
                mocap_cov(par, par[RHO] * (1.0 - a * a), Qm[w, j])


def residual_rows(R_MI: Array, p_MI: Array, R_WM: Array, p_WM: Array, Rbar: Array,
                  pbar: Array, jacobians: bool = True) -> Rows:
    """Residuals (attitude ``Log(Rbar^T R_WM R_MI)``, position ``p_WM + Rbar R_MI^T p_MI -
    pbar``) at every sample of a chunk's windows and the parts of their Jacobians not through
    the sensitivities (without ``jacobians`` only the residuals; the rest is empty), in one
    compiled pass (the numpy formulas' temporaries cost more than the arithmetic)."""
    W, m1 = Rbar.shape[:2]
    shape = (W, m1, 3, 3) if jacobians else (0, 0, 3, 3)
    r = np.empty((W, m1, 6))
    Jinv, Pm_rot, Jp, Hq = (np.empty(shape) for _ in range(4))
    residual_kernel(_c(R_MI), _c(p_MI), _c(R_WM), _c(p_WM), _c(Rbar), _c(pbar), jacobians, r,
                    Jinv, Pm_rot, Jp, Hq)
    return Rows(r, Jinv, Pm_rot, Jp, Hq, np.ascontiguousarray(R_WM[:, 0]))


@kernel(inline=True)
def jacobian_parts(E, J, Q, K, Rbar, r, w, k, Jinv, Pm_rot, Jp,
                   Hq):  # pragma: no cover  (compiled)
    """Sample ``k`` of window ``w``'s Jacobian parts (see :func:`residual_kernel`): ``E`` the
    attitude error, ``J = Rbar R_MI^T``, ``Q = [R_MI^T p_MI]x``, ``K`` work space."""
    p0, p1, p2 = r[w, k, 0], r[w, k, 1], r[w, k, 2]
    t2 = p0 * p0 + p1 * p1 + p2 * p2
    if t2 < 1e-8:
        d = 1.0 / 12.0 + t2 / 720.0
    else:
        t = np.sqrt(t2)
        d = 1.0 / t2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t))
    K[0, 0], K[0, 1], K[0, 2] = 0.0, -p2, p1
    K[1, 0], K[1, 1], K[1, 2] = p2, 0.0, -p0
    K[2, 0], K[2, 1], K[2, 2] = -p1, p0, 0.0
    for i in range(3):
        for j in range(3):
            kk = K[i, 0] * K[0, j] + K[i, 1] * K[1, j] + K[i, 2] * K[2, j]
            Jinv[w, k, i, j] = (1.0 if i == j else 0.0) + 0.5 * K[i, j] + d * kk
    for i in range(3):
        for j in range(3):
            Pm_rot[w, k, i, j] = (Jinv[w, k, i, 0] * E[j, 0] + Jinv[w, k, i, 1] * E[j, 1]
                                  + Jinv[w, k, i, 2] * E[j, 2])
            Jp[w, k, i, j] = J[i, j]
            Hq[w, k, i, j] = (Rbar[w, k, i, 0] * Q[0, j] + Rbar[w, k, i, 1] * Q[1, j]
                              + Rbar[w, k, i, 2] * Q[2, j])


@kernel
def residual_kernel(R_MI, p_MI, R_WM, p_WM, Rbar, pbar, jacobians, r, Jinv, Pm_rot, Jp,
                    Hq):  # pragma: no cover  (compiled)
    """See :func:`residual_rows`: ``E = Rbar^T R_WM R_MI``, its log through the quaternion
    (Shepperd's method, as :func:`~mocap_calib.core.model.so3.log`), the inverse right
    Jacobian there, ``Pm_rot = Jinv E^T``, ``Jp = Rbar R_MI^T``, ``Hq = Rbar [R_MI^T p_MI]x``."""
    W, m1 = Rbar.shape[:2]
    q = np.zeros(3)
    for i in range(3):
        q[i] = R_MI[0, i] * p_MI[0] + R_MI[1, i] * p_MI[1] + R_MI[2, i] * p_MI[2]
    Q = np.zeros((3, 3))
    Q[0, 1], Q[0, 2], Q[1, 0], Q[1, 2], Q[2, 0], Q[2, 1] = -q[2], q[1], q[2], -q[0], -q[1], q[0]
    M, E, J, K = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    qt, v = np.zeros(4), np.zeros(3)
    for w in range(W):
        for k in range(m1):
            for i in range(3):
                for j in range(3):
                    M[i, j] = (R_WM[w, k, i, 0] * R_MI[0, j] + R_WM[w, k, i, 1] * R_MI[1, j]
                               + R_WM[w, k, i, 2] * R_MI[2, j])
            for i in range(3):
                for j in range(3):
                    E[i, j] = (Rbar[w, k, 0, i] * M[0, j] + Rbar[w, k, 1, i] * M[1, j]
                               + Rbar[w, k, 2, i] * M[2, j])
            rot_log(E, qt, v)
            for i in range(3):
                r[w, k, i] = v[i]
            for i in range(3):
                jp = 0.0
                for j in range(3):
                    J[i, j] = (Rbar[w, k, i, 0] * R_MI[j, 0] + Rbar[w, k, i, 1] * R_MI[j, 1]
                               + Rbar[w, k, i, 2] * R_MI[j, 2])
                for j in range(3):
                    jp += J[i, j] * p_MI[j]
                r[w, k, 3 + i] = p_WM[w, k, i] - pbar[w, k, i] + jp
            if not jacobians:
                continue
            jacobian_parts(E, J, Q, K, Rbar, r, w, k, Jinv, Pm_rot, Jp, Hq)
