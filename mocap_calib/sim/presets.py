"""Named simulator configurations: regimes of real flights, declared once.

``flying`` is a drone in flight as a real log shows it: the accelerometer's white noise 10x
its data sheet's density, rotor vibration of 2 m/s^2 RMS (4 rotors wandering in 95-145 Hz
with their second harmonic, aliased by the 200 Hz IMU sampling) and 0.03 rad/s on the gyro,
a Vicon-like mocap at 100 Hz (0.5 mm and 0.2 deg per sample, correlated over 0.3 s), the
bias random walks of the data sheet and a 5 ms clock offset. ``noise`` stays the data
sheet's, which is what a user gives the calibration.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig
from mocap_calib.sim.vibration import Vibration

PRESETS: dict[str, dict[str, Any]] = {
    "none": {},
    "flying": {
        "imu_rate": 200.0,
        "mocap_rate": 100.0,
        "noise": NoiseModel(mocap_position_sigma=0.5e-3,
                            mocap_rotation_sigma=float(np.radians(0.2))),
        "mocap_noise_corr": 0.3,
        "accel_noise_factor": 10.0,
        "vibration": Vibration(accel_rms=2.0, gyro_rms=0.03, band_hz=(95.0, 145.0)),
        "effects": {"time_offset": [0.005]},
    },
}

#: One line per preset, for ``--help``.
PRESET_HELP = {
    "none": "the data sheet's noise, no vibration",
    "flying": "a drone in flight: accel white noise 10x the data sheet's, rotor vibration "
    "2 m/s^2 and 0.03 rad/s RMS at 95-145 Hz with its harmonic (aliased at 200 Hz), mocap "
    "0.5 mm / 0.2 deg correlated over 0.3 s at 100 Hz, bias walks, t_d 5 ms",
}


def preset_config(name: str, vibration: Mapping[str, Any] | None = None,
                  **given: Any) -> SimConfig:
    """The configuration of preset ``name`` with ``given`` :class:`SimConfig` fields over it.

    ``effects`` merge with the preset's (a value given for an effect wins); ``vibration``
    holds :class:`Vibration` fields that replace the preset's.
    """
    if name not in PRESETS:
        raise InputError(f"unknown preset '{name}'; choose one of: {', '.join(PRESETS)}")
    base = dict(PRESETS[name])
    effects = {**base.pop("effects", {}), **given.pop("effects", {})}
    vib = replace(base.pop("vibration", Vibration()), **dict(vibration or {}))
    return SimConfig(**{**base, **given, "effects": effects, "vibration": vib, "preset": name})
