"""The ladder of measurement models: the base model plus effects, each a small unit.

The base model of ``docs/conventions.md`` is

    w_m = w + b_g,        a_m = f + b_a,

with ``f = R_WI^T (a_W - g_W)``. Every effect adds one term, linear in its parameters:

=========================  ======  ==========================================================
effect                     sensor  term added to the measurement
=========================  ======  ==========================================================
gyro_scale_misalignment    gyro    ``(M_g - I) w``          (9 parameters, ``gyro_matrix``)
accel_scale_misalignment   accel   ``(M_a - I) f``          (6, ``accel_matrix`` lower-tri.)
gyro_g_sensitivity         gyro    ``G f``                  (9, ``g_sensitivity``)
gyro_bias_drift            gyro    ``r_g (t - t_mid)``      (3, ``gyro_bias_rate``)
accel_bias_drift           accel   ``r_a (t - t_mid)``      (3, ``accel_bias_rate``)
gravity_magnitude          world   ``|g|`` estimated        (1, ``gravity_magnitude``)
time_offset                world   ``t_d`` estimated        (1, ``time_offset``)
=========================  ======  ==========================================================

``M_a`` is lower-triangular because the IMU frame is the accelerometer's orthogonalised frame; a
full ``M_a`` would trade a rotation with ``R_MI``. The estimator inverts the model sample by
sample; each unit only says how its term depends on its parameters (``basis`` or ``regressor``),
so adding an effect touches no other code.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import InputError

Array = NDArray[np.float64]

Sensor = Literal["gyro", "accel", "world"]
ActsOn = Literal["w", "f", "time", "gravity", "clock"]


def _basis_full() -> Array:
    b = np.zeros((9, 3, 3))
    for k in range(9):
        b[k].flat[k] = 1.0
    return b


def _basis_lower() -> Array:
    idx = [(0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]
    b = np.zeros((6, 3, 3))
    for k, (i, j) in enumerate(idx):
        b[k, i, j] = 1.0
    return b


@dataclass(frozen=True)
class Effect:
    """One rung of the model ladder.

    Attributes:
        name: canonical name (``docs/conventions.md``).
        param: name of its parameter in results (units in ``unit``).
        dim: number of scalar parameters.
        sensor: which measurement the term enters (``world`` for gravity and clock).
        acts_on: ``w``/``f``: a matrix times the true rate / specific force; ``time``: a vector
            times ``t - t_mid``; ``gravity``/``clock``: handled by the world model.
        unit: unit of the parameter, for reports.
        description: one line for ``--help`` and reports.
        limits: plausible magnitudes for a MEMS IMU (names and values, see
            :mod:`mocap_calib.core.model.plausible`); overridable per session.
    """

    name: str
    param: str
    dim: int
    sensor: Sensor
    acts_on: ActsOn
    unit: str
    description: str
    limits: tuple[tuple[str, float], ...] = ()

    @property
    def basis(self) -> Array:
        """(dim, 3, 3) basis matrices of a matrix term: ``E = sum_k theta_k basis_k``."""
        if self.acts_on not in ("w", "f"):
            raise TypeError(f"{self.name} is not a matrix term")
        return _basis_lower() if self.dim == 6 else _basis_full()

    def matrix(self, theta: Array) -> Array:
        """The term's matrix ``E`` (for ``M - I`` or ``G``) from the parameter vector."""
        return np.einsum("k,kij->ij", np.asarray(theta, dtype=float), self.basis)

    def zero(self) -> Array:
        """Parameter value that makes the term vanish (the nested model's identity)."""
        return np.zeros(self.dim)

    def report_value(self, theta: Array) -> object:
        """Parameter in the form the result file shows (matrices as ``M``, not ``M - I``)."""
        theta = np.asarray(theta, dtype=float)
        if self.acts_on in ("w", "f"):
            m = self.matrix(theta)
            if self.name.endswith("scale_misalignment"):
                m = m + np.eye(3)
            return m.tolist()
        if self.dim == 1:
            return float(theta[0])
        return theta.tolist()

    def report_sigma(self, sigma: Array) -> object:
        sigma = np.asarray(sigma, dtype=float)
        if self.acts_on in ("w", "f"):
            return np.einsum("k,kij->ij", sigma, self.basis).tolist()
        if self.dim == 1:
            return float(sigma[0])
        return sigma.tolist()

    def theta_from_report(self, value: object) -> Array:
        """Inverse of :meth:`report_value` (for priors and truth files)."""
        if self.acts_on in ("w", "f"):
            m = np.asarray(value, dtype=float).reshape(3, 3)
            if self.name.endswith("scale_misalignment"):
                m = m - np.eye(3)
            return np.einsum("kij,ij->k", self.basis, m)
        return np.atleast_1d(np.asarray(value, dtype=float)).reshape(self.dim)


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("time_offset", "time_offset", 1, "world", "clock", "s",
               "IMU stamp t was measured at mocap time t + t_d"),
        Effect("gyro_scale_misalignment", "gyro_matrix", 9, "gyro", "w", "-",
               "w_m = M_g w + b_g with M_g near identity (scale and axis misalignment)",
               (("scale", 0.03), ("misalignment_deg", 2.0))),
        Effect("accel_scale_misalignment", "accel_matrix", 6, "accel", "f", "-",
               "a_m = M_a f + b_a with M_a lower-triangular near identity",
               (("scale", 0.03), ("misalignment_deg", 2.0))),
        Effect("gyro_g_sensitivity", "g_sensitivity", 9, "gyro", "f", "rad/s per m/s^2",
               "w_m = w + G f + b_g (gyro responds to specific force)",
               (("max", 1e-3),)),
        Effect("gyro_bias_drift", "gyro_bias_rate", 3, "gyro", "time", "rad/s^2",
               "gyro bias trend beyond the random walk: b_g(t) = b_g + r_g (t - t_mid)",
               (("max", 1e-3),)),
        Effect("accel_bias_drift", "accel_bias_rate", 3, "accel", "time", "m/s^3",
               "accel bias trend beyond the random walk: b_a(t) = b_a + r_a (t - t_mid)",
               (("max", 0.05),)),
        Effect("gravity_magnitude", "gravity_magnitude", 1, "world", "gravity", "m/s^2",
               "|g| differs from the value assumed", (("min", 9.76), ("max", 9.84))),
    )
}

CANONICAL_EFFECTS: tuple[str, ...] = tuple(EFFECTS)


@dataclass(frozen=True)
class Model:
    """A rung of the ladder: the base model plus a set of effects (order kept for reports)."""

    effects: tuple[str, ...] = ()

    @classmethod
    def parse(cls, spec: str) -> Model:
        """Parse ``base+time_offset+gyro_scale_misalignment`` (``base`` is implied)."""
        names = [n.strip() for n in spec.replace(",", "+").split("+") if n.strip()]
        out: list[str] = []
        for n in names:
            if n == "base":
                continue
            if n not in EFFECTS:
                raise InputError(f"unknown effect '{n}' in model '{spec}'; use base plus any of: "
                                 f"{', '.join(CANONICAL_EFFECTS)}")
            if n not in out:
                out.append(n)
        return cls(tuple(out))

    def with_effect(self, name: str) -> Model:
        if name in self.effects:
            return self
        return Model((*self.effects, name))

    def has(self, name: str) -> bool:
        return name in self.effects

    @property
    def units(self) -> list[Effect]:
        return [EFFECTS[n] for n in self.effects]

    def __str__(self) -> str:
        return "+".join(("base", *self.effects))
