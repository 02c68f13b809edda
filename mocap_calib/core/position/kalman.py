"""The window filter's Python side: its noise parameters, the pass over a chunk of windows (the
loops are compiled: :mod:`mocap_calib.core.position.kernels`), the likelihood-only pass and the
state-space model written out (see :mod:`mocap_calib.core.position.engine`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position import kernels as kn
from mocap_calib.core.position.kernels import DIFFUSE  # noqa: F401  (re-exported)
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
    mocap noise (zero when white) and the six mocap variances: attitude per axis in the IMU
    frame, position per axis in the world frame, each times ``axis_scale``."""
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
    return par


def lever_matrix(R_MI: Array, p_MI: Array) -> Array:
    """``[p_MI]x R_MI``: a sample's lever-arm Jacobian is ``R_WM`` times it."""
    x, y, z = p_MI
    return np.ascontiguousarray(np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]) @ R_MI)


@dataclass(frozen=True)
class Whitening:
    """What the filter of a chunk of windows is made of, apart from the residuals: the steps'
    increments and nominal attitudes (for the transitions), the noise parameters, the lever-arm
    matrix and the robust weights. A frozen whitening keeps the one of its recording; these
    arrays (60 numbers a step) are all it holds."""

    inc: Array  # (W, m, 51) packed step increments
    Rbar: Array  # (W, m+1, 3, 3) nominal attitudes
    par: Array  # (N_PAR,) noise parameters
    M: Array  # (3, 3) lever-arm matrix
    weights: Array  # (W, m+1) robust weights


@dataclass(frozen=True)
class Rows:
    """A chunk's residuals and the parts of their Jacobians not through the sensitivities."""

    r: Array  # (W, m+1, 6)
    Jinv: Array  # (W, m+1, 3, 3)
    Pm_rot: Array  # (W, m+1, 3, 3)
    R_WM: Array  # (W, m+1, 3, 3)


def _c(x: Array) -> Array:
    return np.ascontiguousarray(x, dtype=float)


def filter_pass(h: Array, mask: NDArray[np.bool_], now: Whitening, op: Whitening | None,
                rows: Rows, dwf: Array, dg: Array, gcols: list[int], rs: int, ts: int,
                blocks: NDArray[np.int64] | None, store: bool) -> EvalOut:
    """One filter pass over a chunk of windows: ``now`` gives the sensitivities' transitions
    (and, without ``op``, the whitening); ``op`` a frozen whitening to reuse."""
    W, m1 = mask.shape
    p = dwf.shape[-1]
    frozen = op is not None
    op = now if op is None else op
    gram = np.zeros((W, p + 1, p + 1))
    innov, e_white = np.zeros((W, m1, 6)), np.zeros((W, m1, 6))
    d_raw, logdet = np.zeros((W, m1)), np.zeros(W)
    n_blocks = int(blocks[-1]) + 1 if blocks is not None else 0
    scores = np.zeros((W, n_blocks, p))
    raw_J = np.zeros((W, m1, 6, p) if store else (0, 0, 6, p))
    whitened = np.zeros((W, m1, 6, p + 1) if store else (0, 0, 6, p + 1))
    kn.filter_windows(
        _c(h), np.ascontiguousarray(mask), _c(now.weights), _c(now.inc), _c(now.Rbar),
        _c(op.inc), _c(op.Rbar), _c(op.weights), frozen, _c(dwf), _c(dg),
        np.asarray(gcols, dtype=np.int64), _c(rows.r), _c(rows.Jinv), _c(rows.Pm_rot),
        _c(rows.R_WM), _c(op.M), _c(op.par), rs, ts,
        np.zeros(mask.shape[1], np.int64) if blocks is None else blocks,
        gram, innov, e_white, d_raw, logdet, scores, raw_J, whitened)
    e2 = e_white**2
    extras = state_space(h, now, rows.R_WM) if store else {}
    return EvalOut(gram, innov, d_raw, e2.sum(axis=(1, 2)), e2[..., 0:3].sum(axis=2),
                   e2[..., 3:6].sum(axis=2), logdet, scores if blocks is not None else None,
                   rows.r if store else None, raw_J if store else None,
                   whitened if store else None, extras, e_white)


def likelihood_pass(h: Array, mask: NDArray[np.bool_], wh: Whitening, r: Array,
                    R_WM: Array) -> tuple[Array, Array]:
    """(W,) chi2 and log det of the innovations of the residuals ``r`` alone (the filter pass
    without Jacobian columns)."""
    W, m1 = mask.shape
    none = np.zeros((W, m1 - 1, 6, 0))
    rows = Rows(r, R_WM, R_WM, R_WM)  # no Jacobian columns: the Jacobian parts are not read
    out = filter_pass(h, mask, wh, None, rows, none, np.zeros((3, 0)), [], -1, -1, None, False)
    return out.chi2, out.logdet


def state_space(h: Array, wh: Whitening, R_WM: Array) -> dict[str, Array]:
    """The filter's state-space model written out (tests against a dense likelihood):
    transitions ``F``, process noise ``q_diag``/``q_pv``, white mocap noise ``Rn``, the
    weights, and with correlated mocap noise its ``Fm``, ``Qm`` and ``Pm0``."""
    W, m = h.shape
    corr = wh.par[kn.RHO] > 0 and wh.par[kn.T_CORR] > 0
    F, q_diag, q_pv = np.zeros((W, m, 15, 15)), np.zeros((W, m, 15)), np.zeros((W, m))
    Rn = np.zeros((W, m + 1, 6, 6))
    Fm, Qm, Pm0 = np.zeros((W, m, 6, 6)), np.zeros((W, m, 6, 6)), np.zeros((W, 6, 6))
    kn.state_space(_c(wh.inc), _c(wh.Rbar), _c(h), _c(R_WM), _c(wh.M), _c(wh.par), F, q_diag,
                   q_pv, Rn, Fm, Qm, Pm0)
    out = {"F": F, "q_diag": q_diag, "q_pv": q_pv, "Rn": Rn, "weights": wh.weights.copy()}
    if corr:
        out.update(Fm=Fm, Qm=Qm, Pm0=Pm0)
    return out
