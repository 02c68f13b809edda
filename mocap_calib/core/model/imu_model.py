"""The measurement model, both ways: raw IMU samples <-> true rate ``w`` and specific force ``f``.

The model (``docs/conventions.md`` plus the effects in :mod:`mocap_calib.core.model.effects`) is

    a_m = (I + E_a) f + b_a + r_a (u - t_mid)
    w_m = (I + E_g) w + G f + b_g + r_g (u - t_mid)

where ``u`` is the sample's IMU-clock time and every term but the biases comes from an effect
unit. :func:`correct` inverts it and returns, for the parameters of every active effect and the
biases, the sensitivities ``dw/dtheta`` and ``df/dtheta`` that the factors chain into their
Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import EFFECTS, Model

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Intrinsics:
    """Values of the IMU-side effect parameters (keyed by effect name) and the biases."""

    gyro_bias: Array
    accel_bias: Array
    effects: dict[str, Array]
    t_mid: float = 0.0

    def theta(self, name: str) -> Array:
        return self.effects.get(name, EFFECTS[name].zero())


@dataclass(frozen=True)
class Corrected:
    """True-signal estimates and their sensitivities at a set of samples.

    Attributes:
        w: (..., 3) angular rate.
        f: (..., 3) specific force.
        dw: dict effect-or-bias name -> (..., 3, k) ``dw/dtheta``.
        df: dict name -> (..., 3, k) ``df/dtheta``.
        dw_du: (..., 3) time derivative of ``w`` (if raw derivatives were given).
        df_du: (..., 3) time derivative of ``f``.
    """

    w: Array
    f: Array
    dw: dict[str, Array]
    df: dict[str, Array]
    dw_du: Array | None = None
    df_du: Array | None = None


def _matrix_sum(model: Model, params: Intrinsics, sensor: str, acts_on: str) -> Array:
    m = np.zeros((3, 3))
    for eff in model.units:
        if eff.sensor == sensor and eff.acts_on == acts_on:
            m = m + eff.matrix(params.theta(eff.name))
    return m


def correct(model: Model, params: Intrinsics, gyro_m: Array, accel_m: Array, u: Array,
            gyro_dot: Array | None = None, accel_dot: Array | None = None,
            sensitivities: bool = True) -> Corrected:
    """Invert the measurement model sample by sample.

    Args:
        model: active effects.
        params: biases and effect parameters.
        gyro_m: (..., 3) measured rate (rad/s).
        accel_m: (..., 3) measured specific force (m/s^2).
        u: (...) IMU-clock times (s) of the samples (for the drift terms).
        gyro_dot, accel_dot: (..., 3) time derivatives of the raw signals, to get those of the
            corrected ones (needed for the time-offset Jacobian).
        sensitivities: also return ``dw``/``df``.

    Returns:
        The corrected signals and their sensitivities to every parameter block, including
        ``gyro_bias`` and ``accel_bias``.
    """
    Ea = _matrix_sum(model, params, "accel", "f")
    Eg = _matrix_sum(model, params, "gyro", "w")
    G = _matrix_sum(model, params, "gyro", "f")
    Ma_inv = np.linalg.inv(np.eye(3) + Ea)
    Mg_inv = np.linalg.inv(np.eye(3) + Eg)
    du = (u - params.t_mid)[..., None]

    ra = np.zeros(3)
    rg = np.zeros(3)
    for eff in model.units:
        if eff.acts_on == "time":
            if eff.sensor == "accel":
                ra = ra + params.theta(eff.name)
            else:
                rg = rg + params.theta(eff.name)

    f = _affine(accel_m - params.accel_bias, du, ra, None, None, Ma_inv, Ea)
    w = _affine(gyro_m - params.gyro_bias, du, rg, f, G, Mg_inv, Eg)
    dw_du = df_du = None
    if gyro_dot is not None and accel_dot is not None:
        df_du = (accel_dot - ra) @ Ma_inv.T
        dw_du = (gyro_dot - rg - df_du @ G.T) @ Mg_inv.T
    A = None
    r_size = _size_arms(model, params)
    if r_size is not None and (np.any(r_size) or sensitivities):
        # The triad's size terms need the true rate and its derivative: f here is at the
        # accelerometers' positions; take their terms out (w follows through G). Callers
        # without the signals' derivatives (the first stages) get the rate terms only.
        A = size_matrix(w, np.zeros_like(w) if dw_du is None else dw_du)
        f = f - _size_terms(A, r_size)
        w = _affine(gyro_m - params.gyro_bias, du, rg, f, G, Mg_inv, Eg)
    if not sensitivities:
        return Corrected(w, f, {}, {}, dw_du, df_du)
    dw, df = _sensitivities(model, Ma_inv, Mg_inv, G, w, f, du, A)
    return Corrected(w, f, dw, df, dw_du, df_du)


def _affine(x: Array, du: Array, r: Array, f: Array | None, G: Array | None, M_inv: Array,
            E: Array) -> Array:
    """``(x - du r - f G^T) M_inv^T``, skipping the terms of effects the model does not have
    (the same numbers: they would add zeros and multiply by the identity). Called at every
    node of the position stage's integration, where the full form cost as much as the RK4."""
    if np.any(r):
        x = x - du * r
    if f is not None and np.any(G):
        x = x - f @ G.T
    return x @ M_inv.T if np.any(E) else x


def imu_times(model: Model, params: Intrinsics, u: Array) -> Array:
    """When the IMU samples stamped ``u`` were taken, on a clock running at the mocap's rate
    (``clock_drift``: ``u + s (u - t_mid)``; the clock offset is added by the caller)."""
    s = sum((float(params.theta(e.name)[0]) for e in model.units if e.acts_on == "clock_rate"),
            0.0)
    return u if s == 0.0 else u + s * (u - params.t_mid)


def accel_lag(model: Model, params: Intrinsics) -> float:
    """How much later (s) an accel sample is stamped than the gyro sample of the same instant
    (``accel_delay``): the accelerometer's signal at time ``x`` is its samples' at ``x + lag``."""
    return sum((float(params.theta(e.name)[0]) for e in model.units if e.acts_on == "accel_lag"),
               0.0)


def _size_arms(model: Model, params: Intrinsics) -> Array | None:
    units = [e for e in model.units if e.acts_on == "size"]
    if not units:
        return None
    return sum(params.theta(e.name) for e in units)


def size_matrix(w: Array, alpha: Array) -> Array:
    """(..., 3, 3) ``[alpha]x + [w]x [w]x``: the specific force at lever arm ``r`` is
    ``f + A r``."""
    W = so3.hat(w)
    return so3.hat(alpha) + W @ W


def _size_terms(A: Array, r: Array) -> Array:
    """(..., 3): the size terms of the x (at the origin), y and z accelerometers."""
    out = np.zeros(A.shape[:-1])
    out[..., 1] = A[..., 1, :] @ r[0:3]
    out[..., 2] = A[..., 2, :] @ r[3:6]
    return out


def _sensitivities(model: Model, Ma_inv: Array, Mg_inv: Array, G: Array, w: Array, f: Array,
                   du: Array, A: Array | None = None
                   ) -> tuple[dict[str, Array], dict[str, Array]]:
    """``dw/dtheta`` and ``df/dtheta`` of every parameter block at corrected ``w``, ``f``."""
    shape = f.shape[:-1]
    df: dict[str, Array] = {}
    dw: dict[str, Array] = {}
    # Accel-side blocks first: gyro depends on f through G.
    df["accel_bias"] = np.broadcast_to(-Ma_inv, shape + (3, 3))
    for eff in model.units:
        if eff.sensor != "accel":
            continue
        if eff.acts_on == "f":
            # d/dtheta_k of (I + E_a) f = const  ->  df = -Ma^-1 B_k f
            df[eff.name] = -np.einsum("ij,kjl,...l->...ik", Ma_inv, eff.basis, f)
        elif eff.acts_on == "time":
            df[eff.name] = -Ma_inv * du[..., None]
        elif eff.acts_on == "size" and A is not None:
            d = np.zeros(shape + (3, 6))
            d[..., 1, 0:3] = -A[..., 1, :]
            d[..., 2, 3:6] = -A[..., 2, :]
            df[eff.name] = d
    MG = Mg_inv @ G
    for name, d in df.items():
        dw[name] = -np.einsum("ik,...kl->...il", MG, d) if np.any(G) else np.zeros_like(d)
    dw["gyro_bias"] = np.broadcast_to(-Mg_inv, shape + (3, 3))
    for eff in model.units:
        if eff.sensor != "gyro":
            continue
        if eff.acts_on == "w":
            dw[eff.name] = -np.einsum("ij,kjl,...l->...ik", Mg_inv, eff.basis, w)
        elif eff.acts_on == "f":
            dw[eff.name] = -np.einsum("ij,kjl,...l->...ik", Mg_inv, eff.basis, f)
        elif eff.acts_on == "time":
            dw[eff.name] = -Mg_inv * du[..., None]
    zeros = {n: np.zeros(shape + (3, d.shape[-1])) for n, d in dw.items() if n not in df}
    df.update(zeros)
    return dw, df




def forward(model: Model, params: Intrinsics, w: Array, f: Array, u: Array,
            alpha: Array | None = None) -> tuple[Array, Array]:
    """The measurement model forwards: raw gyro and accel for true ``w``, ``f`` at times ``u``
    (``alpha``: the angular acceleration, needed by ``accel_size_effect``).

    The inverse of :func:`correct` (the clock effects act on the sample times instead:
    :func:`imu_times`, :func:`accel_lag`).
    """
    Ea = _matrix_sum(model, params, "accel", "f")
    Eg = _matrix_sum(model, params, "gyro", "w")
    G = _matrix_sum(model, params, "gyro", "f")
    du = (u - params.t_mid)[..., None]
    ra = sum((params.theta(e.name) for e in model.units
              if e.acts_on == "time" and e.sensor == "accel"), np.zeros(3))
    rg = sum((params.theta(e.name) for e in model.units
              if e.acts_on == "time" and e.sensor == "gyro"), np.zeros(3))
    f_sensed = f
    r_size = _size_arms(model, params)
    if r_size is not None and np.any(r_size):
        if alpha is None:
            raise ValueError("accel_size_effect needs the angular acceleration")
        f_sensed = f + _size_terms(size_matrix(w, alpha), r_size)
    accel = f_sensed @ (np.eye(3) + Ea).T + params.accel_bias + du * ra
    gyro = w @ (np.eye(3) + Eg).T + f @ G.T + params.gyro_bias + du * rg
    return gyro, accel

