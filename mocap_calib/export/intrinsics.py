"""Our IMU intrinsics in the parametrisations of Kalibr and OpenVINS.

Ours (``docs/conventions.md``): ``w_m = M_g w + G f + b_g``, ``a_m = M_a f + b_a`` with ``f``
the specific force in the IMU (accelerometer) frame and ``M_a`` lower-triangular.

Kalibr's ``scale-misalignment`` model (``IccScaledMisalignedImu``) for the reference IMU:
``w_m = M C_gyro_i w + A C_gyro_i f + b``, ``a_m = M_acc f + b`` with ``M``, ``M_acc``
lower-triangular and ``C_gyro_i`` a rotation. So ``M_g = M C_gyro_i`` (an LQ decomposition:
lower-triangular times orthogonal) and ``A = G C_gyro_i^T``.

OpenVINS's ``kalibr`` model (``Propagator``: ``a = R_ACCtoIMU Da (a_m - b_a)``,
``w = R_GYROtoIMU Dw (w_m - b_g - Tg a)``, ``Dw = Tw^-1``, ``Da = Ta^-1``):
``w_m = Tw R_IMUtoGYRO w + Tg f + b_g``, ``a_m = Ta R_IMUtoACC f + b_a``. So ``Tw = M``,
``R_IMUtoGYRO = C_gyro_i``, ``Ta = M_a``, ``R_IMUtoACC = I`` and ``Tg = G`` (not Kalibr's ``A``:
OpenVINS applies ``Tg`` to the specific force in the IMU frame, Kalibr ``A`` to it in the gyro
frame; they differ by ``C_gyro_i``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import ActsOn, Sensor, of_term

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ImuIntrinsics:
    """``M_g``, ``G``, ``M_a`` of a result (identity / zero where the model has no effect)."""

    gyro_matrix: Array
    g_sensitivity: Array
    accel_matrix: Array

    @property
    def is_identity(self) -> bool:
        return bool(np.array_equal(self.gyro_matrix, np.eye(3))
                    and not np.any(self.g_sensitivity)
                    and np.array_equal(self.accel_matrix, np.eye(3)))


def intrinsics_of(effects: dict) -> ImuIntrinsics:
    """Read the effect blocks of a result (``effects: {name: {param: value}}``)."""

    def matrix(sensor: Sensor, acts_on: ActsOn) -> Array:
        eff = of_term(sensor, acts_on)  # the matrix term of this sensor and kind
        value = (effects.get(eff.name) or {}).get(eff.param)
        if value is None:  # absent: the term vanishes
            return np.eye(3) if eff.about_identity else np.zeros((3, 3))
        return np.asarray(value, dtype=float).reshape(3, 3)

    return ImuIntrinsics(matrix("gyro", "w"), matrix("gyro", "f"), matrix("accel", "f"))


def lower_times_rotation(m: Array) -> tuple[Array, Array]:
    """``m = L C`` with ``L`` lower-triangular (positive diagonal) and ``C`` a rotation.

    From the QR decomposition of ``m^T``: ``m^T = Q R`` gives ``m = R^T Q^T``; signs are moved
    so that the diagonal of ``L`` is positive, which makes ``C`` a rotation for any ``m`` with
    a positive determinant (a near-identity scale/misalignment matrix).
    """
    q, r = np.linalg.qr(np.asarray(m, dtype=float).T)
    s = np.sign(np.diag(r))
    s[s == 0] = 1.0
    L = (s[:, None] * r).T  # rows of R scaled -> columns of L
    C = (q * s[None, :]).T
    if np.linalg.det(C) < 0:
        raise ValueError("the gyro matrix has a negative determinant (a mirrored axis)")
    return L, C


@dataclass(frozen=True)
class KalibrGyro:
    """Kalibr's gyro intrinsics: ``M`` (lower-triangular), ``A``, ``C_gyro_i``."""

    M: Array
    A: Array
    C_gyro_i: Array


def kalibr_gyro(intr: ImuIntrinsics) -> KalibrGyro:
    L, C = lower_times_rotation(intr.gyro_matrix)
    return KalibrGyro(L, intr.g_sensitivity @ C.T, C)
