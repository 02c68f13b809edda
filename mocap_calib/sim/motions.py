"""Motion kinds other than the random drone flight, for sessions that cannot determine
everything: a turntable (rotation about one fixed vertical axis), a ground robot (planar motion,
yaw only) and slow, low-excitation 3D motion.

Each returns an object with :class:`~mocap_calib.sim.trajectory.Trajectory`'s interface
(position, velocity, acceleration, rotation, body angular velocity), exact at any time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.errors import InputError
from mocap_calib.sim.trajectory import Trajectory, _random_sines, _SineSum, random_trajectory

Array = NDArray[np.float64]

#: ``--motion`` choices: what each simulates.
MOTIONS: dict[str, str] = {
    "flight": "random drone flight (rotates about all axes; the default)",
    "turntable": "rotation about one vertical axis only (a turntable)",
    "planar": "ground robot: planar translation and yaw only",
    "slow": "slow, low-excitation 3D motion (frequencies x0.15)",
}


def _rz(a: Array) -> Array:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((len(a), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


@dataclass(frozen=True)
class TurntableTrajectory:
    """``R_WI = Rz(yaw) R0``, ``p_WI = centre + Rz(yaw) r0``: a rigid body turning about the
    world's vertical axis through ``centre`` with a varying rate."""

    yaw: _SineSum
    R0: Array
    centre: Array
    r0: Array

    def _dz(self, t: Array) -> tuple[Array, Array, Array]:
        return self.yaw.value(t), self.yaw.d1(t), self.yaw.d2(t)

    def position(self, t: Array) -> Array:
        return self.centre + _rz(self.yaw.value(t)) @ self.r0

    def velocity(self, t: Array) -> Array:
        a, da, _ = self._dz(t)
        x, y = self.r0[0], self.r0[1]
        c, s = np.cos(a), np.sin(a)
        return np.stack([da * (-s * x - c * y), da * (c * x - s * y), 0 * a], axis=1)

    def acceleration(self, t: Array) -> Array:
        a, da, dda = self._dz(t)
        x, y = self.r0[0], self.r0[1]
        c, s = np.cos(a), np.sin(a)
        ax = dda * (-s * x - c * y) - da**2 * (c * x - s * y)
        ay = dda * (c * x - s * y) - da**2 * (s * x + c * y)
        return np.stack([ax, ay, 0 * a], axis=1)

    def rotation(self, t: Array) -> Array:
        return _rz(self.yaw.value(t)) @ self.R0

    def angular_velocity_body(self, t: Array) -> Array:
        da = self.yaw.d1(t)
        return np.outer(da, self.R0[2])  # R0^T e_z, scaled by the rate


def _flat(offset: float = 0.0) -> _SineSum:
    return _SineSum(offset, 0.0, np.zeros(1), np.ones(1), np.zeros(1))


def motion_trajectory(kind: str, rng: np.random.Generator,
                      aggressiveness: float = 1.0) -> Trajectory | TurntableTrajectory:
    """The IMU's trajectory for a motion kind (a key of :data:`MOTIONS`)."""
    a = aggressiveness
    if kind == "flight":
        return random_trajectory(rng, aggressiveness=a)
    if kind == "slow":
        return random_trajectory(rng, aggressiveness=0.15 * a)
    if kind == "turntable":
        yaw = _random_sines(rng, 3, 2.0, 0.05 * a, 0.3 * a, rate=0.8 * a)
        R0 = so3.exp(np.radians(rng.uniform(-40, 40, 3)))
        return TurntableTrajectory(yaw, R0, np.array([0.2, -0.1, 1.0]),
                                   np.array([0.3, 0.1, 0.05]))
    if kind == "planar":
        px = _random_sines(rng, 3, 1.7, 0.08 * a, 0.5 * a)
        py = _random_sines(rng, 3, 1.7, 0.08 * a, 0.5 * a)
        yaw = _random_sines(rng, 3, 2.5, 0.05 * a, 0.35 * a, rate=0.2 * a)
        return Trajectory((px, py, _flat(0.1)), (yaw, _flat(), _flat()))
    raise InputError(f"unknown --motion '{kind}'; choose one of: {', '.join(MOTIONS)}")
