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
clock_drift                world   stamp ``t`` at ``t + t_d + s (t - t_mid)``  (1, ``s``)
accel_delay                accel   accel stamp ``t`` at ``t + t_d - delta``   (1, ``delta``)
accel_size_effect          accel   ``e_i.(alpha x r_i + w x (w x r_i))``, i = y, z  (6)
=========================  ======  ==========================================================

``M_a`` is lower-triangular because the IMU frame is the accelerometer's orthogonalised frame; a
full ``M_a`` would trade a rotation with ``R_MI``. The estimator inverts the model sample by
sample; each unit says which kind of term it is (``acts_on``) and how it depends on its
parameters, so adding an effect of an existing kind touches no other code; a new kind is taught
once to :mod:`mocap_calib.core.model.imu_model` (and, for time terms, the engine's step
Jacobian). Each record also says how the simulator draws its truth (:class:`EffectSim`); the
simulator applies the truth by the same kind, with its own written-out measurement model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import GRAVITY
from mocap_calib.errors import InputError

Array = NDArray[np.float64]

Sensor = Literal["gyro", "accel", "world"]
ActsOn = Literal["w", "f", "time", "gravity", "clock", "clock_rate", "accel_lag", "size"]
SimDraw = Literal["matrix", "lower_matrix", "vectors", "value", "signed"]


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
class EffectSim:
    """How the simulator makes the effect's truth (``simulate --effect NAME[=VALUE]``).

    Attributes:
        default: what a bare ``NAME`` injects: the std of a matrix's entries, the length of
            each vector, or the value itself.
        help: what ``VALUE`` means, for ``--help``.
        draw: how the truth is made from one value ``v``: ``matrix``: 3x3 entries drawn from
            N(0, v^2), or the 9 values given (row-major); ``lower_matrix``: the same with the
            upper triangle zeroed; ``vectors``: ``dim / 3`` vectors of length ``v`` in random
            directions, or the ``dim`` values given; ``value``: ``v`` itself; ``signed``: ``v``
            itself, and without a value the default with a random sign.
        non_negative: a single value is a magnitude (a std, a length), never negative.
        bounds: the open interval a value must lie in, if any.
    """

    default: float
    help: str
    draw: SimDraw = "value"
    non_negative: bool = False
    bounds: tuple[float, float] | None = None

    def value_counts(self, dim: int) -> tuple[int, ...]:
        """How many values ``VALUE`` may hold: one, or the whole matrix or vector(s)."""
        if self.draw in ("matrix", "lower_matrix"):
            return (1, 9)
        if self.draw == "vectors":
            return (1, dim)
        return (1,)


@dataclass(frozen=True)
class Effect:
    """One rung of the model ladder.

    Attributes:
        name: canonical name (``docs/conventions.md``).
        param: name of its parameter in results (units in ``unit``).
        dim: number of scalar parameters.
        sensor: which measurement the term enters (``world`` for gravity and clock).
        acts_on: the kind of term, each handled once by the measurement model and the engine:
            ``w``/``f``: a matrix times the true rate / specific force; ``time``: a vector
            times ``t - t_mid``; ``gravity``/``clock``: the world's ``|g|`` and the clock
            offset (own graph variables); ``clock_rate``: the IMU clock's rate error (sample
            times stretched about ``t_mid``); ``accel_lag``: the accelerometer's samples
            shifted in time against the gyro's; ``size``: the accelerometer triad's lever arms
            (terms in the angular rate and acceleration).
        unit: unit of the parameter, for reports.
        description: one line for ``--help`` and reports.
        limits: plausible magnitudes for a MEMS IMU (names and values, see
            :mod:`mocap_calib.core.plausible`); overridable per session.
        range_sigma: the weak prior around the start value (parameter units) that keeps
            every graph well posed; a parameter whose posterior sigma is not well below it
            was not determined by the data (:mod:`mocap_calib.core.model.parameters`).
        about_identity: a matrix term reported (and judged plausible) as ``M = I + E``, a
            scale-and-misalignment matrix near identity, rather than as ``E`` itself.
        sim: how the simulator draws its truth (every registered effect has one).
    """

    name: str
    param: str
    dim: int
    sensor: Sensor
    acts_on: ActsOn
    unit: str
    description: str
    limits: tuple[tuple[str, float], ...] = ()
    range_sigma: float = 0.05  # weak prior (1 sigma) that keeps the graph well posed
    about_identity: bool = False
    sim: EffectSim | None = None

    @property
    def in_effects(self) -> bool:
        """Its parameters form an effect vector (all but the clock offset and ``|g|``, which
        are world variables of their own)."""
        return self.acts_on not in ("clock", "gravity")

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
            if self.about_identity:
                m = m + np.eye(3)
            return m.tolist()
        if self.acts_on == "size":
            return {"r_y": theta[0:3].tolist(), "r_z": theta[3:6].tolist()}
        if self.dim == 1:
            return float(theta[0])
        return theta.tolist()

    def report_sigma(self, sigma: Array) -> object:
        sigma = np.asarray(sigma, dtype=float)
        if self.acts_on in ("w", "f"):
            return np.einsum("k,kij->ij", sigma, self.basis).tolist()
        if self.acts_on == "size":
            return {"r_y": sigma[0:3].tolist(), "r_z": sigma[3:6].tolist()}
        if self.dim == 1:
            return float(sigma[0])
        return sigma.tolist()

    def theta_from_report(self, value: object) -> Array:
        """Inverse of :meth:`report_value` (for priors and truth files)."""
        if self.acts_on in ("w", "f"):
            m = np.asarray(value, dtype=float).reshape(3, 3)
            if self.about_identity:
                m = m - np.eye(3)
            return np.einsum("kij,ij->k", self.basis, m)
        if self.acts_on == "size" and isinstance(value, dict):
            return np.r_[np.asarray(value["r_y"], float), np.asarray(value["r_z"], float)]
        return np.atleast_1d(np.asarray(value, dtype=float)).reshape(self.dim)


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("time_offset", "time_offset", 1, "world", "clock", "s",
               "IMU stamp t was measured at mocap time t + t_d",
               range_sigma=0.05,
               sim=EffectSim(0.005, "t_d in s (IMU stamp t was measured at mocap time t + t_d)")),
        Effect("gyro_scale_misalignment", "gyro_matrix", 9, "gyro", "w", "-",
               "w_m = M_g w + b_g with M_g near identity (scale and axis misalignment)",
               (("scale", 0.03), ("misalignment_deg", 2.0)),
               range_sigma=0.05, about_identity=True,
               sim=EffectSim(0.003, "std of the entries of M_g - I, or 9 values row-major",
                             "matrix", non_negative=True)),
        Effect("accel_scale_misalignment", "accel_matrix", 6, "accel", "f", "-",
               "a_m = M_a f + b_a with M_a lower-triangular near identity",
               (("scale", 0.03), ("misalignment_deg", 2.0)),
               range_sigma=0.05, about_identity=True,
               sim=EffectSim(0.003, "std of the entries of the lower-triangular M_a - I, or 9 "
                             "values", "lower_matrix", non_negative=True)),
        Effect("gyro_g_sensitivity", "g_sensitivity", 9, "gyro", "f", "rad/s per m/s^2",
               "w_m = w + G f + b_g (gyro responds to specific force)",
               (("max", 1e-3),),
               range_sigma=0.01,
               sim=EffectSim(3e-4, "std of the entries of G in rad/s per m/s^2, or 9 values",
                             "matrix", non_negative=True)),
        Effect("gyro_bias_drift", "gyro_bias_rate", 3, "gyro", "time", "rad/s^2",
               "gyro bias trend beyond the random walk: b_g(t) = b_g + r_g (t - t_mid)",
               (("max", 1e-3),),
               range_sigma=1e-3,
               sim=EffectSim(2e-5, "trend magnitude in rad/s per s, or 3 values", "vectors",
                             non_negative=True)),
        Effect("accel_bias_drift", "accel_bias_rate", 3, "accel", "time", "m/s^3",
               "accel bias trend beyond the random walk: b_a(t) = b_a + r_a (t - t_mid)",
               (("max", 0.05),),
               range_sigma=0.05,
               sim=EffectSim(2e-3, "trend magnitude in m/s^2 per s, or 3 values", "vectors",
                             non_negative=True)),
        Effect("gravity_magnitude", "gravity_magnitude", 1, "world", "gravity", "m/s^2",
               "|g| differs from the value assumed", (("min", 9.76), ("max", 9.84)),
               range_sigma=0.5,
               sim=EffectSim(9.79, f"true |g| in m/s^2 (the calibration assumes {GRAVITY})",
                             non_negative=True, bounds=(5.0, 15.0))),
        Effect("clock_drift", "clock_drift", 1, "world", "clock_rate", "-",
               "the IMU clock runs at another rate: IMU stamp t was measured at mocap time "
               "t + t_d + s (t - t_mid)", (("max", 1e-3),),
               range_sigma=2e-3,
               sim=EffectSim(1e-4, "IMU clock rate error s (1e-4 = 100 ppm); default: 100 ppm, "
                             "random sign", "signed")),
        Effect("accel_delay", "accel_delay", 1, "accel", "accel_lag", "s",
               "the accelerometer lags the gyro: an accel sample stamped t measured the specific "
               "force at mocap time t + t_d - delta", (("max", 0.02),),
               range_sigma=0.05,
               sim=EffectSim(0.004, "how much the accelerometer lags the gyro, in s")),
        Effect("accel_size_effect", "accel_size_effect", 6, "accel", "size", "m",
               "accelerometer triad size effect: the y and z accelerometers sit at r_y, r_z "
               "(IMU frame), a_m,i = e_i.(f + alpha x r_i + w x (w x r_i)) + b_a,i",
               (("max", 0.03),),
               range_sigma=0.1,
               sim=EffectSim(0.01, "distance of the y and z accelerometers from the x one (m, "
                             "random directions), or 6 values r_y, r_z", "vectors",
                             non_negative=True)),
    )
}

CANONICAL_EFFECTS: tuple[str, ...] = tuple(EFFECTS)

#: Kinds with exactly one effect: world variables of their own in every graph (the clock
#: offset and |g|), in the order the layouts put them.
WORLD_KINDS: tuple[ActsOn, ...] = ("clock", "gravity")


def of_kind(kind: ActsOn) -> Effect:
    """The one effect of a single-member kind (:data:`WORLD_KINDS`)."""
    (eff,) = [e for e in EFFECTS.values() if e.acts_on == kind]
    return eff


def of_term(sensor: Sensor, acts_on: ActsOn) -> Effect:
    """The one effect of a sensor's term kind, e.g. ``("gyro", "f")``: the gyro's
    g-sensitivity."""
    (eff,) = [e for e in EFFECTS.values() if e.sensor == sensor and e.acts_on == acts_on]
    return eff


#: The clock offset t_d (its name is also the result file's key, and its base-parameter record
#: :data:`~mocap_calib.core.model.parameters.TIME_OFFSET` shares it) and the world's |g|.
CLOCK_OFFSET: Effect = of_kind("clock")
GRAVITY_MAGNITUDE: Effect = of_kind("gravity")


@dataclass(frozen=True)
class Model:
    """A rung of the ladder: the base model plus a set of effects (order kept for reports).
    ``auto``: the effects are to be chosen from the session (the diagnosis' tests)."""

    effects: tuple[str, ...] = ()
    auto: bool = False

    @classmethod
    def parse(cls, spec: str) -> Model:
        """Parse ``base+time_offset+gyro_scale_misalignment`` (``base`` is implied), or
        ``auto``."""
        if spec.strip() == "auto":
            return cls(auto=True)
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

    def has_kind(self, kind: str) -> bool:
        """Whether an effect of this kind (``Effect.acts_on``) is in the model."""
        return any(e.acts_on == kind for e in self.units)

    @property
    def timed(self) -> bool:
        """Whether the clock offset is a variable of this model."""
        return self.has_kind("clock")

    def world_units(self) -> list[Effect]:
        """The model's world variables (:data:`WORLD_KINDS`), in layout order."""
        return [e for k in WORLD_KINDS for e in self.units if e.acts_on == k]

    def __str__(self) -> str:
        return "auto" if self.auto else "+".join(("base", *self.effects))
