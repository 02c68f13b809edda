"""Rotor vibration as a logged IMU sees it.

Each rotor spins at a speed ``f_r(t)`` (rev/s, i.e. the fundamental's frequency in Hz) that
wanders slowly inside a band (a thrust demand common to all rotors plus each rotor's own
part, both sums of slow sinusoids bounded to the band). A rotor shakes the airframe with a
sinusoid of phase ``Phi_r(t) = 2 pi int f_r dt + phi_r`` and its second harmonic (weaker),
each along a fixed direction of the IMU frame: mostly the thrust axis (``z`` of ``I``) for the
specific force, any axis for the angular rate. The phase is integrated analytically and the
signal is evaluated at the true instants of the IMU samples: sampled at the IMU rate, a
line above the Nyquist frequency folds back (at 200 Hz a 145 Hz line lands at 55 Hz, the
harmonic of a 98 Hz rotor at 4 Hz), as in a real log. An optional first-order low-pass ahead
of the sampling (an anti-alias filter) scales and delays each line by its response at the
line's instantaneous frequency (the speeds change slowly against the filter's time constant);
it acts on the vibration only, so the slow motion keeps no filter delay and the clock offset
stays the simulated one.

The vibration is a true specific force and rate at the sensor; its displacement (micrometres)
and rotation (1e-4 rad) are far below the mocap noise and are not added to the poses.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import InputError

Array = NDArray[np.float64]

#: Slow sinusoids in each rotor's speed (common thrust demand, and each rotor's own part).
_WANDER_TERMS = 3
#: Lowest frequency of the speed changes (Hz).
_WANDER_MIN_HZ = 0.02


@dataclass(frozen=True)
class Vibration:
    """Rotor vibration of a simulated flight (off with both levels 0).

    Attributes:
        accel_rms: RMS of the vibration's specific force, all three axes together (m/s^2),
            before any anti-alias filter.
        gyro_rms: the same on the angular rate (rad/s).
        band_hz: the rotors' speeds (the fundamental, Hz) stay inside ``[lo, hi]``.
        rotors: number of rotors.
        harmonic: amplitude of the second harmonic relative to the fundamental.
        lateral: spread of each specific-force line's direction off the thrust axis (the x
            and y parts are this times a standard normal draw, z is 1, then normalised).
        wander_hz: the fastest component of the speed changes (Hz).
        anti_alias_hz: cut-off of a first-order low-pass ahead of the sampling; 0: none.
    """

    accel_rms: float = 0.0
    gyro_rms: float = 0.0
    band_hz: tuple[float, float] = (95.0, 145.0)
    rotors: int = 4
    harmonic: float = 0.5
    lateral: float = 0.35
    wander_hz: float = 0.5
    anti_alias_hz: float = 0.0

    @property
    def on(self) -> bool:
        return self.accel_rms > 0.0 or self.gyro_rms > 0.0

    def validate(self) -> None:
        lo, hi = self.band_hz
        checks = (
            (0.0 <= self.accel_rms <= 100.0, f"accel RMS {self.accel_rms:g} m/s^2: give 0 "
             "(off) to 100"),
            (0.0 <= self.gyro_rms <= 10.0, f"gyro RMS {self.gyro_rms:g} rad/s: give 0 (off) "
             "to 10"),
            (0.0 < lo <= hi <= 1e4, f"rotor band {lo:g}-{hi:g} Hz: give 0 < low <= high <= "
             "10000"),
            (1 <= self.rotors <= 12, f"{self.rotors} rotors: give 1 to 12"),
            (0.0 <= self.harmonic <= 1.0, f"harmonic {self.harmonic:g}: give 0 to 1 (relative "
             "to the fundamental)"),
            (0.0 <= self.lateral <= 10.0, f"lateral spread {self.lateral:g}: give 0 to 10"),
            (_WANDER_MIN_HZ <= self.wander_hz <= 10.0, f"speed wander {self.wander_hz:g} Hz: "
             f"give {_WANDER_MIN_HZ:g} to 10"),
            (self.anti_alias_hz == 0.0 or 1.0 <= self.anti_alias_hz <= 1e4,
             f"anti-alias cut-off {self.anti_alias_hz:g} Hz: give 0 (none) or 1 to 10000"),
        )
        for ok, msg in checks:
            if not ok:
                raise InputError(f"vibration: {msg}")


@dataclass(frozen=True)
class Rotors:
    """The drawn rotors: speed laws, phases and the lines' amplitude vectors.

    ``amp_accel[r, k]`` / ``amp_gyro[r, k]``: the 3-vector amplitude of rotor ``r``'s
    harmonic ``k + 1`` (m/s^2, rad/s); ``coef``, ``freq``, ``phase``: each rotor's speed
    wander ``u_r(t) = sum_j coef sin(2 pi freq t + phase)`` with ``|u_r| <= 1``,
    ``f_r = mid + half u_r``.
    """

    vib: Vibration
    coef: Array  # (rotors, terms)
    freq: Array
    phase: Array
    line_phase: Array  # (rotors, 2): phase of each harmonic at t = 0
    amp_accel: Array  # (rotors, 2, 3)
    amp_gyro: Array

    def speed(self, t: Array) -> Array:
        """Rotor speeds (Hz), (rotors, N)."""
        lo, hi = self.vib.band_hz
        arg = 2 * np.pi * self.freq[:, :, None] * t + self.phase[:, :, None]
        u = np.einsum("rj,rjn->rn", self.coef, np.sin(arg))
        return 0.5 * (lo + hi) + 0.5 * (hi - lo) * u

    def turns(self, t: Array) -> Array:
        """``int_0^t f_r dt`` (revolutions), (rotors, N): the speed law integrated exactly."""
        lo, hi = self.vib.band_hz
        w = 2 * np.pi * self.freq[:, :, None]
        arg = w * t + self.phase[:, :, None]
        integral = -(np.cos(arg) - np.cos(self.phase[:, :, None])) / w
        return 0.5 * (lo + hi) * t + 0.5 * (hi - lo) * np.einsum("rj,rjn->rn", self.coef,
                                                                 integral)

    def signal(self, t: Array, amp: Array) -> Array:
        """The vibration at true times ``t`` (N, 3) for line amplitudes ``amp``."""
        out = np.zeros((len(t), 3))
        turns = self.turns(t)
        speed = self.speed(t)
        for k in range(2):
            arg = 2 * np.pi * (k + 1) * turns + self.line_phase[:, k, None]
            gain, lag = self.filter_response((k + 1) * speed)
            out += np.einsum("rn,ri->ni", gain * np.sin(arg - lag), amp[:, k])
        return out

    def filter_response(self, f: Array) -> tuple[Array, Array]:
        """Gain and phase lag of the anti-alias filter at frequencies ``f`` (1, 0 without)."""
        if self.vib.anti_alias_hz <= 0.0:
            return np.ones_like(f), np.zeros_like(f)
        x = f / self.vib.anti_alias_hz
        return 1.0 / np.sqrt(1.0 + x * x), np.arctan(x)


def draw_rotors(rng: np.random.Generator, vib: Vibration) -> Rotors:
    """The rotors of one flight, every draw from ``rng`` in a fixed order."""
    n, k = vib.rotors, _WANDER_TERMS

    def bounded(size: tuple[int, ...]) -> tuple[Array, Array, Array]:
        c = rng.uniform(0.5, 1.0, size)
        return (c / c.sum(axis=-1, keepdims=True), rng.uniform(_WANDER_MIN_HZ, vib.wander_hz,
                                                               size),
                rng.uniform(0.0, 2 * np.pi, size))

    common = bounded((k,))
    own = bounded((n, k))
    # Half common thrust demand, half each rotor's own: |u_r| <= 1 keeps f_r in the band.
    coef = np.concatenate([np.broadcast_to(0.5 * common[0], (n, k)), 0.5 * own[0]], axis=1)
    freq = np.concatenate([np.broadcast_to(common[1], (n, k)), own[1]], axis=1)
    phase = np.concatenate([np.broadcast_to(common[2], (n, k)), own[2]], axis=1)
    line_phase = rng.uniform(0.0, 2 * np.pi, (n, 2))
    d_acc = rng.normal(size=(n, 2, 3)) * np.array([vib.lateral, vib.lateral, 0.0])
    d_acc[..., 2] = 1.0
    d_gyr = rng.normal(size=(n, 2, 3))
    weights = np.array([1.0, vib.harmonic])[None, :, None]
    return Rotors(vib, coef, freq, phase, line_phase,
                  _scaled(d_acc, weights, vib.accel_rms), _scaled(d_gyr, weights, vib.gyro_rms))


def _scaled(directions: Array, weights: Array, rms: float) -> Array:
    """Unit directions times the line weights, scaled so that the lines' total mean square
    (each line ``|a|^2 / 2``, independent phases) is ``rms^2``."""
    a = directions / np.linalg.norm(directions, axis=-1, keepdims=True) * weights
    total = 0.5 * np.sum(a * a)
    return a * (rms / np.sqrt(total)) if total > 0 else a


def alias(f: Array, rate: float) -> Array:
    """Where a line at ``f`` lands after sampling at ``rate``: folded into [0, rate / 2]."""
    return np.abs(f - rate * np.round(f / rate))


#: The band (Hz, from 0) in which the calibration takes in the IMU's noise (see
#: :func:`effective_density`).
EFFECTIVE_BAND_HZ = 5.0


def effective_density(rotors: Rotors, amp: Array, t: Array, imu_rate: float,
                      band_hz: float = EFFECTIVE_BAND_HZ) -> Array:
    """Per axis, the white density (Kalibr units: the square root of the two-sided power
    spectral density) with the vibration's power, as sampled at the IMU rate (aliased), in
    ``[0, band_hz]``: ``q^2 = P[0, B] / (2 B)``, averaged over the instants ``t`` (a line
    counts while its alias lies in the band; the speeds wander).

    Why this band: the calibration compares the accelerometer's double integral with the
    mocap's positions, and the double integral scales an error at frequency ``f`` by
    ``1 / (2 pi f)^2``: above a few Hz the mocap's noise (0.5 mm at 100 Hz) hides an
    accelerometer noise of the levels seen in flight (0.02-0.15 m/s^2/sqrt(Hz) cross over
    at 3-9 Hz), below it the accelerometer's noise is what the position windows see. A
    harmonic aliased near 0 Hz (a rotor near half the IMU rate) counts fully, lines aliased
    to 50-100 Hz not at all. Checked against the accelerometer level the calibration's
    windows' likelihood prefers on vibration-only flights (2 m/s^2, 60 s): it found 0.015 for
    a 95-145 Hz band (this definition: 0.014-0.015), 0.15 for 97-100 Hz (0.16) and the data
    sheet's 0.002 for 130-131 Hz (0).
    """
    speed = rotors.speed(t)
    power = np.zeros(3)
    for k in range(2):
        f = (k + 1) * speed
        gain, _ = rotors.filter_response(f)
        w = np.mean(gain**2 * (alias(f, imu_rate) <= band_hz), axis=1)  # per rotor
        power += 0.5 * np.einsum("r,ri->i", w, amp[:, k] ** 2)
    return np.sqrt(power / (2.0 * band_hz))


def vibration_truth(rotors: Rotors, t: Array, imu_rate: float) -> dict[str, object]:
    """The truth file's record of the vibration: its settings, the rotor speeds' ranges and
    the effective white densities (:func:`effective_density`)."""
    speed = rotors.speed(t)
    vib = rotors.vib
    return {
        **{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(vib).items()},
        "rotor_speed_range_hz": [[float(s.min()), float(s.max())] for s in speed],
        "effective_density_accel": effective_density(rotors, rotors.amp_accel, t,
                                                     imu_rate).tolist(),
        "effective_density_gyro": effective_density(rotors, rotors.amp_gyro, t,
                                                    imu_rate).tolist(),
        "effective_density_band_hz": [0.0, EFFECTIVE_BAND_HZ],
        "effective_density_definition": "per axis, the white density (units/sqrt(Hz)) with "
        "the power the vibration, as sampled at the IMU rate (aliased), has in the band: "
        "q^2 = P[0, B] / (2 B), averaged over the flight; the band is where the calibration's "
        "position windows see the IMU's noise",
    }
