"""Smooth, drone-like IMU trajectories with analytic derivatives.

Position: a sum of sinusoids per axis around the room centre. Attitude: ZYX Euler angles
(yaw unbounded, roll/pitch within +-40 deg), each a sum of sinusoids, so the body angular
velocity has a closed form. Everything is evaluated exactly at any time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class _SineSum:
    """``f(t) = offset + rate * t + sum_j amp_j sin(2 pi freq_j t + phase_j)``."""

    offset: float
    rate: float
    amp: Array
    freq: Array
    phase: Array

    def value(self, t: Array) -> Array:
        arg = 2 * np.pi * self.freq * t[:, None] + self.phase
        return self.offset + self.rate * t + np.sin(arg) @ self.amp

    def d1(self, t: Array) -> Array:
        w = 2 * np.pi * self.freq
        return self.rate + np.cos(2 * np.pi * self.freq * t[:, None] + self.phase) @ (self.amp * w)

    def d2(self, t: Array) -> Array:
        w = 2 * np.pi * self.freq
        arg = 2 * np.pi * self.freq * t[:, None] + self.phase
        return -np.sin(arg) @ (self.amp * w * w)

    def plus(self, more: _SineSum) -> _SineSum:
        """This function plus ``more``'s sinusoids (its offset and rate are ignored)."""
        return _SineSum(self.offset, self.rate, np.r_[self.amp, more.amp],
                        np.r_[self.freq, more.freq], np.r_[self.phase, more.phase])


def _random_sines(rng: np.random.Generator, n: int, total_amp: float, fmin: float, fmax: float,
                  offset: float = 0.0, rate: float = 0.0) -> _SineSum:
    freq = rng.uniform(fmin, fmax, n)
    weights = rng.uniform(0.5, 1.0, n)
    amp = total_amp * weights / weights.sum()
    phase = rng.uniform(0, 2 * np.pi, n)
    return _SineSum(offset, rate, amp, freq, phase)


@dataclass(frozen=True)
class Trajectory:
    """IMU-frame trajectory ``T_WI(t)`` in the mocap world ``W``.

    Attributes:
        pos: per-axis position functions (m).
        euler: yaw, pitch, roll functions (rad), ``R_WI = Rz(yaw) Ry(pitch) Rx(roll)``.
    """

    pos: tuple[_SineSum, _SineSum, _SineSum]
    euler: tuple[_SineSum, _SineSum, _SineSum]

    def position(self, t: Array) -> Array:
        return np.stack([f.value(t) for f in self.pos], axis=1)

    def velocity(self, t: Array) -> Array:
        return np.stack([f.d1(t) for f in self.pos], axis=1)

    def acceleration(self, t: Array) -> Array:
        return np.stack([f.d2(t) for f in self.pos], axis=1)

    def rotation(self, t: Array) -> Array:
        yaw, pitch, roll = (f.value(t) for f in self.euler)
        cy, sy = np.cos(yaw), np.sin(yaw)
        cp, sp = np.cos(pitch), np.sin(pitch)
        cr, sr = np.cos(roll), np.sin(roll)
        R = np.empty((len(t), 3, 3))
        R[:, 0, 0] = cy * cp
        R[:, 0, 1] = cy * sp * sr - sy * cr
        R[:, 0, 2] = cy * sp * cr + sy * sr
        R[:, 1, 0] = sy * cp
        R[:, 1, 1] = sy * sp * sr + cy * cr
        R[:, 1, 2] = sy * sp * cr - cy * sr
        R[:, 2, 0] = -sp
        R[:, 2, 1] = cp * sr
        R[:, 2, 2] = cp * cr
        return R

    def angular_velocity_body(self, t: Array) -> Array:
        """``w_I``: angular velocity of ``I`` relative to ``W``, expressed in ``I`` (rad/s)."""
        _, pitch, roll = (f.value(t) for f in self.euler)
        dyaw, dpitch, droll = (f.d1(t) for f in self.euler)
        sp, cp = np.sin(pitch), np.cos(pitch)
        sr, cr = np.sin(roll), np.cos(roll)
        return np.stack([
            droll - dyaw * sp,
            dpitch * cr + dyaw * cp * sr,
            -dpitch * sr + dyaw * cp * cr,
        ], axis=1)


def random_trajectory(rng: np.random.Generator, room_half_extent: float = 2.0,
                      height: float = 1.3, aggressiveness: float = 1.0) -> Trajectory:
    """A random smooth flight inside a mocap room.

    Args:
        rng: random generator (the only source of randomness).
        room_half_extent: the flight stays within +-this many metres horizontally.
        height: mean flight height (m); vertical excursions stay within +-0.8 m.
        aggressiveness: scales frequencies (1.0 gives peaks near 1 g and 3 rad/s).
    """
    a = aggressiveness
    px = _random_sines(rng, 3, 0.85 * room_half_extent, 0.08 * a, 0.5 * a)
    py = _random_sines(rng, 3, 0.85 * room_half_extent, 0.08 * a, 0.5 * a)
    pz = _random_sines(rng, 3, 0.6, 0.1 * a, 0.6 * a, offset=height)
    yaw = _random_sines(rng, 3, 2.5, 0.05 * a, 0.35 * a, offset=rng.uniform(-np.pi, np.pi),
                        rate=rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.3) * a)
    pitch = _random_sines(rng, 4, np.radians(40.0), 0.1 * a, 0.9 * a)
    roll = _random_sines(rng, 4, np.radians(40.0), 0.1 * a, 0.9 * a)
    return Trajectory((px, py, pz), (yaw, pitch, roll))


#: Peak contributions of the fast components of :func:`with_fast_motion`, per axis: the sum of
#: their amplitudes times (2 pi f) for the attitude angles (rad/s), times (2 pi f)^2 for the
#: position (m/s^2). With the flight's own peaks (near 3 rad/s and 1 g) the body stays below
#: about 5 rad/s and 3 g.
FAST_RATE_RADPS = 0.8
FAST_ACCEL_MPS2 = 3.0


def _fast_sines(rng: np.random.Generator, n: int, budget: float, power: int, fmin: float,
                fmax: float) -> _SineSum:
    freq = rng.uniform(fmin, fmax, n)
    weights = rng.uniform(0.5, 1.0, n)
    amp = budget * weights / weights.sum() / (2 * np.pi * freq) ** power
    return _SineSum(0.0, 0.0, amp, freq, rng.uniform(0, 2 * np.pi, n))


def with_fast_motion(traj: Trajectory, rng: np.random.Generator, max_hz: float) -> Trajectory:
    """``traj`` plus small vibration-like components between 1 Hz and ``max_hz`` on every
    position axis and attitude angle (4 each), sized by their rate and acceleration (see
    :data:`FAST_RATE_RADPS`) so that the fast ones matter as much as the slow ones."""
    fmin = min(1.0, max_hz)
    pos = tuple(f.plus(_fast_sines(rng, 4, FAST_ACCEL_MPS2, 2, fmin, max_hz)) for f in traj.pos)
    euler = tuple(f.plus(_fast_sines(rng, 4, FAST_RATE_RADPS, 1, fmin, max_hz))
                  for f in traj.euler)
    return Trajectory(pos, euler)  # type: ignore[arg-type]


def periodic_trajectory(rng: np.random.Generator, period: float, room_half_extent: float = 2.0,
                        height: float = 1.3) -> Trajectory:
    """A flight that repeats itself every ``period`` seconds (every frequency a multiple of
    ``1 / period``, no yaw drift): its signals look the same at lags of whole periods, so no
    clock search can tell those lags apart."""
    def sines(n: int, amp: float, kmax: int, offset: float = 0.0) -> _SineSum:
        k = rng.integers(1, kmax + 1, n)
        w = rng.uniform(0.5, 1.0, n)
        return _SineSum(offset, 0.0, amp * w / w.sum(), k / period, rng.uniform(0, 2 * np.pi, n))

    pos = (sines(3, 0.85 * room_half_extent, 2), sines(3, 0.85 * room_half_extent, 2),
           sines(3, 0.6, 3, offset=height))
    euler = (sines(3, 2.5, 2, offset=rng.uniform(-np.pi, np.pi)),
             sines(4, np.radians(40.0), 4), sines(4, np.radians(40.0), 4))
    return Trajectory(pos, euler)
