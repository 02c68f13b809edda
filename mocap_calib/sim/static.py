"""Simulated long static IMU logs with a known noise model, for Allan-variance tests.

Every channel is ``constant bias + white noise + random walk (+ flicker)`` on top of the
specific force of an IMU at rest (``f = -g R_WI^T g_dir``; Earth rotation is ignored, as in
``docs/conventions.md``). The terms have the continuous-time densities of Kalibr's
``imu.yaml``:

* white noise ``N``: discrete std ``N sqrt(rate)``, Allan variance ``N^2 / tau``;
* random walk ``K``: increments of std ``K sqrt(dt)``, Allan variance ``K^2 tau / 3``;
* bias instability ``B`` (optional): flicker noise with two-sided PSD ``B^2 / (2 pi f)``,
  shaped in the frequency domain, Allan deviation floor ``0.664 B``.

Everything is vectorised (one FFT per flicker channel), so hours at 200 Hz take seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, NoiseModel
from mocap_calib.core.policy import GRAVITY
from mocap_calib.errors import InputError

Array = NDArray[np.float64]


def flicker_noise(rng: np.random.Generator, n: int, rate_hz: float, B: float,
                  channels: int = 3) -> Array:
    """Flicker (1/f) noise with two-sided PSD ``B^2 / (2 pi |f|)`` above ``rate_hz / n``.

    Args:
        rng: random generator.
        n: number of samples.
        rate_hz: sample rate.
        B: bias instability (the Allan deviation floor is ``0.664 B``).
        channels: number of independent columns.

    Returns:
        (n, channels) samples.
    """
    if B <= 0 or n < 2:
        return np.zeros((n, channels))
    # Generate on an FFT-friendly length (a prime n would be slow) and keep the first n.
    L = scipy.fft.next_fast_len(n, real=True)
    f = np.fft.rfftfreq(L, 1.0 / rate_hz)
    psd = np.zeros_like(f)
    psd[1:] = B * B / (2.0 * np.pi * f[1:])
    # E|X_k|^2 = L * rate * S(f_k) makes irfft's output have variance sum(S) df.
    amp = np.sqrt(L * rate_hz * psd)
    z = (rng.normal(size=(channels, len(f))) + 1j * rng.normal(size=(channels, len(f))))
    z /= np.sqrt(2.0)
    if L % 2 == 0:
        z[:, -1] = z[:, -1].real * np.sqrt(2.0)  # the Nyquist bin is real
    return scipy.fft.irfft(amp * z, n=L, axis=1)[:, :n].T


def simulate_static(
    seed: int,
    duration_s: float,
    rate_hz: float = 200.0,
    noise: NoiseModel | None = None,
    bias_instability: tuple[float, float] | None = None,
    gravity: float = GRAVITY,
    tilt_deg: float = 2.0,
    time_origin_ns: int = 1_600_000_000_000_000_000,
) -> tuple[ImuSamples, dict[str, Any]]:
    """Simulate a static IMU log with known white noise, random walk and flicker noise.

    Args:
        seed: seed of the single random generator (same seed, same output).
        duration_s: length of the log in s.
        rate_hz: sample rate.
        noise: densities (Kalibr units); default EuRoC's ADIS16448 values.
        bias_instability: ``(gyro B in rad/s, accel B in m/s^2)`` of an added flicker
            component, or None for none.
        gravity: ``|g|`` in m/s^2.
        tilt_deg: the IMU rests tilted by this angle about a random horizontal axis.
        time_origin_ns: stamp of the first sample.

    Returns:
        The IMU samples and a truth dict: the noise model's densities, ``bias_instability``
        per sensor, the initial biases, the constant attitude ``R_WI`` and the gravity.
    """
    if not duration_s > 0:
        raise InputError(f"duration_s={duration_s}: must be positive")
    if not 1.0 <= rate_hz <= 10000.0:
        raise InputError(f"rate_hz={rate_hz}: must be between 1 and 10000 Hz")
    if duration_s * rate_hz > 5e7:
        raise InputError(f"{duration_s:g} s at {rate_hz:g} Hz is more than 5e7 samples; "
                         "simulate a shorter log or a lower rate")
    noise = NoiseModel() if noise is None else noise
    B_g, B_a = bias_instability if bias_instability is not None else (0.0, 0.0)
    rng = np.random.default_rng(seed)

    axis = np.array([*rng.normal(size=2), 0.0])
    R_WI = so3.exp(np.radians(tilt_deg) * axis / np.linalg.norm(axis))
    bg0 = rng.uniform(-0.02, 0.02, 3)
    ba0 = rng.uniform(-0.2, 0.2, 3)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    dt = 1.0 / rate_hz

    def channel(N: float, K: float, B: float) -> Array:
        x = rng.normal(0.0, N * np.sqrt(rate_hz), (n, 3))
        x += np.cumsum(rng.normal(0.0, K * np.sqrt(dt), (n, 3)), axis=0)
        x += flicker_noise(rng, n, rate_hz, B)
        return x

    f_I = gravity * (R_WI.T @ np.array([0.0, 0.0, 1.0]))
    gyro = bg0 + channel(noise.gyroscope_noise_density, noise.gyroscope_random_walk, B_g)
    accel = f_I + ba0 + channel(noise.accelerometer_noise_density,
                                noise.accelerometer_random_walk, B_a)
    imu = ImuSamples(t, gyro, accel, time_origin_ns, "simulated static imu")
    truth: dict[str, Any] = {
        "gyroscope_noise_density": float(noise.gyroscope_noise_density),
        "gyroscope_random_walk": float(noise.gyroscope_random_walk),
        "accelerometer_noise_density": float(noise.accelerometer_noise_density),
        "accelerometer_random_walk": float(noise.accelerometer_random_walk),
        "gyroscope_bias_instability": float(B_g),
        "accelerometer_bias_instability": float(B_a),
        "gyro_bias_initial": bg0.tolist(),
        "accel_bias_initial": ba0.tolist(),
        "R_WI": R_WI.tolist(),
        "gravity_magnitude": float(gravity),
        "simulation": {"seed": int(seed), "duration": float(t[-1]), "rate_hz": float(rate_hz),
                       "protocol": "static"},
    }
    return imu, truth
