"""Does each IMU sensor measure the motion the poses show, at a clock offset?

When the first fits are poor and no other reading of the data explains them, the two streams
either do not belong together (neither sensor follows the poses better than at offsets known to
be wrong) or one sensor does not measure the motion. A flight whose gyro follows the poses while
its accelerometer does not (a loose or saturating accelerometer, a filter that lets the rotors'
vibration through, a mean the motion cannot explain) cannot give the accelerometer-dependent
quantities, and the position stage needs them all. This module measures both sensors' agreement
on the closed-form grid of :mod:`~mocap_calib.core.prepare.kinematics`, low-passed where the
mocap's noise allows, and words what it finds with its sizes:

- the gyro: the residual of the best rotation between its rates and the poses' body rates, as
  a fraction of the motion, against the same at offsets seconds away (chance);
- the accelerometer: per axis, the correlation of its low-passed specific force with the one
  the poses imply (``R_MI^T R_WM^T (a_W - g_W)``, with ``R_MI`` from the gyro and the world's
  up the axis-aligned one nearest the measured mean), the mean it reads beyond that, and its
  vibration above the band (RMS and main frequency), beside the poses' own acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.prepare.kinematics import (
    SmoothedImu,
    mocap_grid,
    overlap,
    rotation_fit,
    smoothing_of,
)
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]

#: The gyro follows the poses when its rotation misfit is below this fraction of chance's.
CHANCE = 0.6
#: The accelerometer follows the poses when every axis correlates at least this well ...
MIN_CORRELATION = 0.5
#: ... of the axes on which the poses' specific force varies by this much (m/s^2, std).
MIN_VARIATION = 0.1
#: Offsets (s) known to be wrong, for the chance level.
WRONG_OFFSETS = (-9.0, -6.0, -4.0, 4.0, 6.0, 9.0)
AXES = "xyz"


@dataclass(frozen=True)
class SensorAgreement:
    """Both sensors against the poses at clock offset ``t_d`` (see the module's text).

    Attributes:
        t_d: the clock offset (s, on the raw stamps).
        rotation_ratio: the gyro's misfit / the motion; rotation_chance: the same at wrong
            offsets (median).
        correlation: (3,) per IMU axis, low-passed specific force against the poses' (NaN
            where the poses' varies too little to judge).
        unexplained_mean: (3,) m/s^2 the accelerometer reads beyond the poses' mean.
        vibration_rms: (3,) m/s^2 of the accelerometer above the band; vibration_hz: the main
            frequency of the strongest axis.
        motion_rms: the poses' own acceleration (m/s^2, RMS per world axis).
        band_hz: the band's edge (Hz): the low-pass's half-power frequency.
    """

    t_d: float
    rotation_ratio: float
    rotation_chance: float
    correlation: Array
    unexplained_mean: Array
    vibration_rms: Array
    vibration_hz: float
    motion_rms: float
    band_hz: float

    @property
    def gyro_agrees(self) -> bool:
        return self.rotation_ratio < CHANCE * self.rotation_chance

    @property
    def accel_agrees(self) -> bool:
        """No axis with variation to judge by (NaN correlation) counts against it."""
        return not bool(np.any(self.correlation < MIN_CORRELATION))

    def accel_refusal(self) -> str:
        """One line: the accelerometer does not measure the motion, with the sizes."""
        k = int(np.argmax(self.vibration_rms))
        return (
            "the accelerometer does not measure the motion the mocap poses show, the gyro does "
            f"(at clock offset {1e3 * self.t_d:.1f} ms its rates differ from the poses' by "
            f"{self.rotation_ratio:.2f} of the motion, {self.rotation_chance:.2f} by chance): "
            f"below {self.band_hz:.1f} Hz its specific force follows the poses' with "
            f"correlation {_triple(self.correlation, '.2f')} (x, y, z; a working one is near "
            f"1), it reads a mean of {_triple(self.unexplained_mean, '.1f')} m/s^2 that the "
            f"motion does not explain and vibrates by {self.vibration_rms[k]:.1f} m/s^2 RMS at "
            f"{self.vibration_hz:.0f} Hz on {AXES[k]}, while the poses' own acceleration is "
            f"{self.motion_rms:.2f} m/s^2 RMS; the calibration needs both sensors: check the "
            "accelerometer (mounting, range, filtering) or calibrate with another recording")


def _triple(x: Array, fmt: str) -> str:
    return ", ".join(f"{v:{fmt}}" if np.isfinite(v) else "-" for v in x)


def sensor_agreement(s: PreparedSession, t_d: float,
                     gravity: float = GRAVITY) -> SensorAgreement | None:
    """Both sensors' agreement with the poses at ``t_d`` (None: too little overlap or
    motion to judge)."""
    imu = SmoothedImu.of(s)
    delta = s.clock_shift + t_d
    ov = overlap(s, delta, 0.5)
    if ov is None:
        return None
    gr = mocap_grid(s, s.R_WM, s.p_WM, *ov)
    ok = gr.ok & imu.clear(gr.T - delta)
    if ok.sum() < 200:
        return None
    g_I, f_I = imu.at(gr.T[ok] - delta)
    ratio, _, _, Q, _ = rotation_fit(g_I, gr.w_M[ok])
    chance = _rotation_chance(s, imu, t_d)
    if chance is None:
        return None
    R = gr.R[ok]
    a_W = gr.a_W[ok]
    # The world's up: the axis-aligned direction nearest the mean specific force (the
    # accelerometer's reading, turned into the world by the poses and the gyro's R_MI).
    mean_W = np.mean(np.einsum("nij,jk,nk->ni", R, Q, f_I), axis=0)
    up = np.zeros(3)
    i = int(np.argmax(np.abs(mean_W)))
    up[i] = np.sign(mean_W[i])
    f_pred = np.einsum("ji,nkj,nk->ni", Q, R, a_W + gravity * up)
    corr = np.array([_corr(f_I[:, j], f_pred[:, j]) if np.std(f_pred[:, j]) >= MIN_VARIATION
                     else np.nan for j in range(3)])
    vib, hz = _vibration(s, imu.width)
    width = smoothing_of(s)
    return SensorAgreement(
        t_d=t_d, rotation_ratio=ratio, rotation_chance=chance, correlation=corr,
        unexplained_mean=np.mean(f_I - f_pred, axis=0), vibration_rms=vib, vibration_hz=hz,
        motion_rms=float(np.sqrt(np.mean((a_W - a_W.mean(axis=0)) ** 2))),
        band_hz=float(np.sqrt(np.log(2.0)) / (2.0 * np.pi * width)))


def _corr(a: Array, b: Array) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def _rotation_chance(s: PreparedSession, imu: SmoothedImu, t_d: float) -> float | None:
    """Median rotation misfit at offsets seconds away from ``t_d`` (known to be wrong)."""
    out = []
    for d in WRONG_OFFSETS:
        delta = s.clock_shift + t_d + d
        ov = overlap(s, delta, 0.5)
        if ov is None:
            continue
        gr = mocap_grid(s, s.R_WM, s.p_WM, *ov)
        ok = gr.ok & imu.clear(gr.T - delta)
        if ok.sum() >= 200:
            out.append(rotation_fit(imu.at(gr.T[ok] - delta)[0], gr.w_M[ok])[0])
    return float(np.median(out)) if len(out) >= 2 else None


def _vibration(s: PreparedSession, width: float) -> tuple[Array, float]:
    """The accelerometer above the band: RMS per axis (m/s^2) and the main frequency (Hz) of
    the strongest axis (the peak of its spectrum, smoothed over 1 Hz)."""
    rate = s.imu_rate
    k = np.arange(-int(4 * width * rate), int(4 * width * rate) + 1)
    g = np.exp(-0.5 * (k / (width * rate)) ** 2)
    low = np.stack([np.convolve(s.accel[:, i], g / g.sum(), mode="same") for i in range(3)],
                   axis=1)
    high = (s.accel - low)[len(k):-len(k)]
    rms = np.sqrt(np.mean(high**2, axis=0))
    j = int(np.argmax(rms))
    spec = np.abs(np.fft.rfft(high[:, j])) ** 2
    freq = np.fft.rfftfreq(len(high), 1.0 / rate)
    m = max(1, int(round(1.0 / max(freq[1], 1e-9))))
    smooth = np.convolve(spec, np.ones(m) / m, mode="same")
    return rms, float(freq[int(np.argmax(smooth))])


def refuse_unmeasured_motion(s: PreparedSession, t_d: float, gravity: float = GRAVITY) -> None:
    """Raise when the gyro follows the poses at ``t_d`` but the accelerometer does not.

    Raises:
        ObservabilityError: the accelerometer does not measure the motion (one line, with
            the gyro's agreement, the accelerometer's per-axis correlation, unexplained mean
            and vibration).
    """
    found = sensor_agreement(s, t_d, gravity)
    if found is not None and found.gyro_agrees and not found.accel_agrees:
        raise ObservabilityError(found.accel_refusal())
