"""The base parameters of the calibration: one record each, the one vocabulary of the code.

=================  ======  ========  ===================================================
parameter          symbol  dim/val   value and perturbation
=================  ======  ========  ===================================================
gyro_bias          b_g     3 / 3     rad/s, IMU frame, ``b_g + delta``
accel_bias         b_a     3 / 3     m/s^2, IMU frame, ``b_a + delta``
rotation           R_MI    3 / 4     quaternion wxyz (``w >= 0``), ``R_MI Exp(delta)``
translation        p_MI    3 / 3     m, marker frame, ``p_MI + delta``
gravity            -       2 / 3     unit vector along ``g_W``, GTSAM ``Unit3`` tangent
time_offset        t_d     1 / 1     s, ``t_d + delta`` (the clock-offset effect)
=================  ======  ========  ===================================================

A parameter's ``name`` is its key everywhere inside the code: the position stage's covariance
blocks and priors, ``unobservable:`` in result files. Its ``symbol`` keys the sections that
discuss the sigmas (``uncertainty:``, ``consistency:``, ``sensitivity:``) and the notes;
``value_key`` and ``sigma_key`` are where the file keeps the value and the sigma. Code acts on
a parameter through this record (``PARAMETERS``, the constants below, ``compared``,
``per_take``, ``form``), never by a string; ``tests/test_effect_names.py`` checks it. The
clock offset is also an effect (:data:`~mocap_calib.core.model.effects.CLOCK_OFFSET`: a model
may fix it); its record here shares the effect's name and range.

Ranges: every parameter and effect has a weak prior (1 sigma, :data:`RANGE_SIGMA`) that keeps
every graph well posed; a parameter whose posterior sigma is not well below it
(:data:`UNOBSERVABLE_RATIO`) was not determined by the data and is reported as unobservable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import CLOCK_OFFSET, EFFECTS

Array = NDArray[np.float64]

#: How a parameter's value is held and perturbed: a plain vector (``value + delta``), a
#: rotation ``so3`` (quaternion in files, ``R Exp(delta)``) or a direction ``s2`` (unit
#: vector, GTSAM ``Unit3``).
Form = Literal["vector", "so3", "s2"]

DEG = float(np.degrees(1.0))


@dataclass(frozen=True)
class Printed:
    """How reports show a parameter: row label, units and factors from SI of the value and
    of the sigma, significant digits of the value."""

    label: str
    value_unit: str
    sigma_unit: str
    value_scale: float = 1.0
    sigma_scale: float = 1.0
    digits: int = 4

    @property
    def unit(self) -> str:
        """The unit column of a table row: one unit, or the value's with the sigma's."""
        if self.value_unit == self.sigma_unit:
            return self.value_unit
        return f"{self.value_unit} (sigma {self.sigma_unit})"


@dataclass(frozen=True)
class Parameter:
    """One base parameter.

    Attributes:
        name: the key in the code, the position stage's block, ``sigma:`` and ``unobservable:``.
        symbol: how the sigma's sections (``uncertainty``, ``consistency``, ``sensitivity``)
            and the notes name it.
        dim: tangent dimension (the sigma's length).
        value_dim: the value's length (4: quaternion wxyz; 3: unit vector; 1: a scalar).
        form: how it is held and perturbed (:data:`Form`).
        unit: SI unit of the value and of the sigma (radians for the tangent of rotations).
        frame: the frame its components are in.
        perturbation: the tangent convention its covariance and sigma use.
        printed: how reports show it.
        value_key: where the result file keeps the value (nested keys).
        sigma_key: its key under the file's ``sigma:``.
        range_sigma: the weak prior of every graph (parameter units, tangent).
        useful_sigma: the sigma beyond which the number is of no use (unobservable).
        per_take: each take has its own (a power cycle changes it), not the rig.
        compared: the segments, the takes and the noise models compare it (the rig's geometry
            and the clock; the text summary details its sigma's terms).
        description: one line.
    """

    name: str
    symbol: str
    dim: int
    value_dim: int
    form: Form
    unit: str
    frame: str
    perturbation: str
    printed: Printed
    value_key: tuple[str, ...]
    sigma_key: str
    range_sigma: float
    useful_sigma: float
    per_take: bool
    compared: bool
    description: str

    @property
    def scalar(self) -> bool:
        """One number (files write it bare, not as a list)."""
        return self.value_dim == 1

    def state(self, value: Array) -> Array:
        """The value as the graphs hold it (a rotation as its matrix)."""
        v = np.asarray(value, dtype=float)
        return so3.quat_to_rotmat(v) if self.form == "so3" else v

    def value_of(self, state: Array) -> Array:
        """Inverse of :meth:`state` (a rotation matrix as its quaternion wxyz)."""
        s = np.asarray(state, dtype=float)
        return so3.rotmat_to_quat(s) if self.form == "so3" else np.atleast_1d(s)

    def difference(self, ref: Array, state: Array) -> Array:
        """``state`` minus ``ref`` in the tangent space at ``ref`` (states, see :meth:`state`)."""
        if self.form == "so3":
            return so3.log(np.asarray(ref).T @ np.asarray(state))
        if self.form == "s2":
            import gtsam  # only where a direction is compared (reading a result needs none)

            u = gtsam.Unit3(np.asarray(ref, dtype=float))
            return np.asarray(u.localCoordinates(gtsam.Unit3(np.asarray(state, dtype=float))))
        return np.atleast_1d(np.asarray(state, dtype=float) - np.asarray(ref, dtype=float))

    def chart(self, ref: Array, state: Array) -> Array:
        """Coordinates of ``state`` in a chart around ``ref``: the tangent at ``ref`` for a
        rotation or direction, the vector itself otherwise (for trends through values)."""
        if self.form == "vector":
            return np.asarray(state, dtype=float).ravel()
        return self.difference(ref, state)

    def from_chart(self, ref: Array, x: Array) -> Array:
        """Inverse of :meth:`chart`."""
        if self.form == "so3":
            return np.asarray(ref) @ so3.exp(x)
        if self.form == "s2":
            import gtsam

            return gtsam.Unit3(np.asarray(ref, dtype=float)).retract(x).point3()
        return x


PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("gyro_bias", "gyro_bias", 3, 3, "vector", "rad/s", "IMU",
                  "b_g + delta", Printed("gyro_bias", "rad/s", "rad/s"), ("gyro_bias",),
                  "gyro_bias",
                  range_sigma=0.5, useful_sigma=0.01, per_take=True, compared=False,
                  description="gyro bias, the session's mean"),
        Parameter("accel_bias", "accel_bias", 3, 3, "vector", "m/s^2", "IMU",
                  "b_a + delta", Printed("accel_bias", "m/s^2", "m/s^2"), ("accel_bias",),
                  "accel_bias",
                  range_sigma=2.0, useful_sigma=0.2, per_take=True, compared=False,
                  description="accelerometer bias, the session's mean"),
        Parameter("rotation", "R_MI", 3, 4, "so3", "rad", "IMU (tangent)",
                  "R_MI = R_MI_est Exp(delta), delta along the IMU axes (GTSAM Rot3)",
                  Printed("R_MI", "deg", "deg", DEG, DEG), ("T_marker_imu", "rotation_wxyz"),
                  "rotation", range_sigma=0.5, useful_sigma=float(np.radians(2.0)), per_take=False,
                  compared=True, description="rotation of T_MI, the IMU's axes in the marker "
                  "frame (quaternion wxyz)"),
        Parameter("translation", "p_MI", 3, 3, "vector", "m", "marker",
                  "p_MI + delta", Printed("p_MI", "mm", "mm", 1e3, 1e3),
                  ("T_marker_imu", "translation"), "translation",
                  range_sigma=0.5, useful_sigma=0.05, per_take=False, compared=True,
                  description="translation of T_MI, the IMU's origin in the marker frame"),
        Parameter("gravity", "gravity", 2, 3, "s2", "rad", "mocap world",
                  "GTSAM Unit3 tangent at the estimate (tilt along its two basis vectors)",
                  Printed("gravity_in_mocap", "-", "deg", 1.0, DEG, digits=6),
                  ("gravity_in_mocap",), "gravity_in_mocap",
                  range_sigma=0.3, useful_sigma=float(np.radians(2.0)), per_take=False,
                  compared=False, description="direction of gravity in the mocap world"),
        Parameter(CLOCK_OFFSET.name, "t_d", 1, 1, "vector", CLOCK_OFFSET.unit, "-",
                  "t_d + delta", Printed(CLOCK_OFFSET.name, "ms", "ms", 1e3, 1e3),
                  (CLOCK_OFFSET.param,), CLOCK_OFFSET.param,
                  range_sigma=CLOCK_OFFSET.range_sigma, useful_sigma=0.005, per_take=True,
                  compared=True, description=CLOCK_OFFSET.description),
    )
}

GYRO_BIAS, ACCEL_BIAS, ROTATION, TRANSLATION, GRAVITY_DIRECTION, TIME_OFFSET = PARAMETERS.values()

#: The parameters the segments, takes and noise models compare, in registry order.
COMPARED: tuple[Parameter, ...] = tuple(p for p in PARAMETERS.values() if p.compared)
#: Those each take has its own.
PER_TAKE: tuple[Parameter, ...] = tuple(p for p in PARAMETERS.values() if p.per_take)

#: Weak priors (1 sigma) that only regularise, per block (base parameters and effects).
RANGE_SIGMA: dict[str, float] = {
    **{p.name: p.range_sigma for p in PARAMETERS.values()},
    **{e.name: e.range_sigma for e in EFFECTS.values()},
}
#: Posterior/prior sigma ratio above which a parameter counts as not determined by the data.
UNOBSERVABLE_RATIO = 0.3


def by_symbol(symbol: str) -> Parameter:
    """The parameter a section of a result file names by its symbol (file boundary)."""
    for p in PARAMETERS.values():
        if p.symbol == symbol:
            return p
    raise KeyError(f"unknown parameter '{symbol}'")
