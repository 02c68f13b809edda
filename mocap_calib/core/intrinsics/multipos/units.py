"""Raw sensor counts: their conversion to nominal SI units, the starting point of a raw-count
calibration, and imu_tk's ``T K (raw - b)`` form of the result.

A raw reading is turned into a nominal SI reading by ``x = scale * (raw - offset)`` per axis
(:class:`RawConversion`); the measurement model ``a_m = M_a f + b_a`` of ``docs/conventions.md``
then holds for ``x``. The conversion is only a change of units: the calibration estimates the
true scales, misalignments and biases whatever it is, and its quality figures do not depend on
it (they are computed in calibrated units).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples

Array = NDArray[np.float64]


def _vec3(value: Any, name: str) -> Array:
    a = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    if not np.all(np.isfinite(a)):
        raise ValueError(f"'{name}' must be 1 or 3 finite numbers")
    return a


@dataclass(frozen=True)
class RawConversion:
    """Raw counts to nominal SI: ``accel = accel_scale (raw - accel_offset)`` in m/s^2,
    ``gyro = gyro_scale (raw - gyro_offset)`` in rad/s, per axis.

    Attributes:
        accel_scale: (3,) m/s^2 per count.
        accel_offset: (3,) counts.
        gyro_scale: (3,) rad/s per count.
        gyro_offset: (3,) counts.
        source: ``given`` (a datasheet's nominal values), ``fitted`` (imu_tk's ``K`` of this
            calibration, zero offset) or ``start`` (the starting point found from the data).
    """

    accel_scale: Array
    accel_offset: Array
    gyro_scale: Array
    gyro_offset: Array
    source: str = "given"

    def __post_init__(self) -> None:
        for name in ("accel_scale", "accel_offset", "gyro_scale", "gyro_offset"):
            object.__setattr__(self, name, _vec3(getattr(self, name), name))
        for name in ("accel_scale", "gyro_scale"):
            if not np.all(getattr(self, name) > 0):
                raise ValueError(f"'{name}' must be positive")

    @classmethod
    def identity(cls, source: str = "identity") -> RawConversion:
        return cls(np.ones(3), np.zeros(3), np.ones(3), np.zeros(3), source)

    def apply(self, imu: ImuSamples) -> ImuSamples:
        """The samples in nominal SI units."""
        return ImuSamples(imu.t, (imu.gyro - self.gyro_offset) * self.gyro_scale,
                          (imu.accel - self.accel_offset) * self.accel_scale,
                          imu.time_origin_ns, imu.source)

    def scale(self, sensor: str) -> Array:
        return self.accel_scale if sensor == "accel" else self.gyro_scale

    def offset(self, sensor: str) -> Array:
        return self.accel_offset if sensor == "accel" else self.gyro_offset

    def to_dict(self) -> dict[str, Any]:
        return {"accel_scale": self.accel_scale.tolist(),
                "accel_offset": self.accel_offset.tolist(),
                "gyro_scale": self.gyro_scale.tolist(), "gyro_offset": self.gyro_offset.tolist(),
                "source": self.source}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RawConversion:
        return cls(d["accel_scale"], d["accel_offset"], d["gyro_scale"], d["gyro_offset"],
                   str(d.get("source", "given")))


def change_units(M: Array, b: Array, src: RawConversion, dst: RawConversion, sensor: str
                 ) -> tuple[Array, Array]:
    """``(M, b)`` of ``x = M y + b`` re-expressed from readings converted by ``src`` to readings
    converted by ``dst`` (same raw counts). ``M`` may be any matrix acting on the true
    quantity (the scale-misalignment matrix or ``G``); pass ``b = 0`` to convert ``M`` alone."""
    r = dst.scale(sensor) / src.scale(sensor)
    # raw = o_s + x_s / s_s, x_d = s_d (raw - o_d) = r x_s + s_d (o_s - o_d).
    return M * r[:, None], r * b + dst.scale(sensor) * (src.offset(sensor) - dst.offset(sensor))


def imu_tk_form(M: Array, b: Array) -> tuple[Array, Array, Array]:
    """imu_tk's ``T, K, b`` with ``T K (x - b) = M^-1 (x - b)``: ``K`` diagonal, ``T`` with a
    unit diagonal (misalignments), ``b`` unchanged.

    Args:
        M: (3, 3) matrix of ``x = M f + b``.
        b: (3,) bias of the same reading.
    """
    A = np.linalg.inv(M)
    K = np.diag(np.diag(A))
    T = A / np.diag(A)[None, :]
    return T, K, np.asarray(b, dtype=float)


def ellipsoid_start(means: Array, gravity: float) -> tuple[Array, Array] | None:
    """Per-axis scale and offset from static means by an axis-aligned ellipsoid fit.

    Solves ``sum_c p_c x_c^2 + q_c x_c = 1`` by linear least squares: the centre is the
    offset, the semi-axes map to ``|g|``. Exact for a sensor without misalignment, and a start
    within the misalignments' order (1e-3) otherwise. Needs 6 or more well spread means.

    Returns:
        (scale (3,), offset (3,)) for :class:`RawConversion`, or None if the means do not
        determine an ellipsoid.
    """
    if len(means) < 6:
        return None
    # Centre and normalise first so the linear system is well conditioned in any unit.
    c0 = means.mean(axis=0)
    r0 = float(np.median(np.linalg.norm(means - c0, axis=1)))
    if not r0 > 0:
        return None
    y = (means - c0) / r0
    A = np.hstack([y * y, y])
    sol, *_ = np.linalg.lstsq(A, np.ones(len(y)), rcond=None)
    p, q = sol[:3], sol[3:]
    if not np.all(p > 0):
        return None
    centre = -q / (2.0 * p)
    R = 1.0 + float(np.sum(q * q / (4.0 * p)))
    if not R > 0:
        return None
    semi = np.sqrt(R / p) * r0
    return gravity / semi, c0 + centre * r0
