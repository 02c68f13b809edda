"""What a calibration can be told: the options of ``calibrate`` that reach the core."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.plausible import PlausibleLimits
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.position.graph import Prior
from mocap_calib.errors import InputError


@dataclass
class CalibrationOptions:
    """Everything a calibration can be told.

    Attributes:
        model: base model plus effects (default: ``base+time_offset``).
        gravity: assumed ``|g|`` (m/s^2).
        noise: IMU and mocap noise (default: EuRoC ADIS16448, Vicon).
        attitude_spacing: keyframe spacing of the attitude factors (s).
        velocity_spacing: keyframe spacing of the velocity factors (s).
        window: length of the position-factor windows (s).
        max_mocap_rate: the position stage decimates faster mocap streams to this rate (Hz).
        time_offset: a known ``t_d`` (s); with ``time_offset`` in the model it is the start
            value instead of the coarse search.
        max_offset: search the clock offset only within +-this many seconds of the raw stamps.
        priors: earlier results entering as prior factors.
        robust: down-weight mocap outliers.
        adapt_noise: re-estimate the mocap noise level from the residuals.
        start, end: calibrate only this part of the session (s from the IMU start).
        max_iterations: most LM iterations per solve.
        consistency_segments: calibrate this many time segments on their own and compare them
            (0: skip).
        sensitivity: refit with the IMU noise densities scaled by 3 and 1/3.
        plausible: the limits of a physically possible answer.
        accept_implausible: return an implausible answer (marked) instead of refusing it.
    """

    model: Model = field(default_factory=lambda: Model(("time_offset",)))
    gravity: float = GRAVITY
    noise: NoiseModel = field(default_factory=NoiseModel)
    attitude_spacing: float = 0.5
    velocity_spacing: float = 0.5
    window: float = 5.0
    max_mocap_rate: float = 120.0
    time_offset: float | None = None
    max_offset: float | None = None
    priors: list[Prior] = field(default_factory=list)
    robust: bool = True
    adapt_noise: bool = True
    start: float | None = None
    end: float | None = None
    max_iterations: int = 30
    consistency_segments: int = 3
    sensitivity: bool = True
    plausible: PlausibleLimits = field(default_factory=PlausibleLimits)
    accept_implausible: bool = False

    def validate(self) -> None:
        if not 5.0 < self.gravity < 15.0:
            raise InputError(f"--gravity {self.gravity}: give |g| in m/s^2 (about {GRAVITY})")
        for name, v, lo, hi in (("--attitude-spacing", self.attitude_spacing, 0.02, 10.0),
                                ("--velocity-spacing", self.velocity_spacing, 0.05, 10.0),
                                ("--window", self.window, 0.5, 60.0)):
            if not lo <= v <= hi:
                raise InputError(f"{name} {v}: must be between {lo} and {hi} s")
        if not 1 <= self.max_iterations <= 10_000:
            raise InputError(f"--max-iterations {self.max_iterations}: must be between 1 and "
                             "10000")
        nz = self.noise
        for k, v in nz.to_dict().items():
            if k.startswith("mocap_noise_corr"):
                continue
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"noise model: {k} = {v} must be a positive number")
        if not (0.0 <= nz.mocap_noise_corr_time <= 10.0
                and 0.0 <= nz.mocap_noise_corr_fraction < 1.0):
            raise InputError("noise model: mocap_noise_corr_time must be 0-10 s and "
                             "mocap_noise_corr_fraction in [0, 1)")
