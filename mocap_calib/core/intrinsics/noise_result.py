"""Results of the Allan-variance noise characterisation and their versioned plain-data form
(kind ``noise``; Kalibr ``imu.yaml`` keys right after ``kind``/``version``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.versioned import check_kind, header

Array = NDArray[np.float64]

KIND = "noise"
VERSION = 1
#: Keys that identify a noise file written before ``kind`` existed.
LEGACY_KEYS = ("gyroscope_noise_density", "accelerometer_noise_density", "per_axis", "allan")


@dataclass(frozen=True)
class SensorNoise:
    """Noise parameters of one triad (per axis) and the curves they were fitted to.

    Attributes:
        sensor: ``"gyroscope"`` or ``"accelerometer"``.
        noise_density: (3,) white noise ``N`` (rad/s/sqrt(Hz) or m/s^2/sqrt(Hz)).
        random_walk: (3,) rate random walk ``K`` (rad/s^2/sqrt(Hz) or m/s^3/sqrt(Hz));
            NaN where not resolved.
        random_walk_fit: (3,) the fitted ``K`` even where not resolved (0: not seen).
        bias_instability: (3,) minimum of the fitted Allan deviation / 0.664 (rad/s or
            m/s^2); an upper bound on ``B`` where white noise or random walk still contribute.
        bias_instability_raw: (3,) minimum of the measured curve / 0.664 (noisier).
        bias_instability_fit: (3,) the fitted flicker term ``B``.
        noise_density_sigma: (3,) 1-sigma of ``N`` from the fit.
        random_walk_sigma: (3,) 1-sigma of ``K`` from the fit.
        random_walk_resolved: (3,) whether ``K`` is determined (relative sigma below 0.3).
        tau_at_minimum: (3,) ``tau`` of the fitted curve's minimum, s.
        tau: (m,) averaging times, s.
        adev: (3, m) overlapping Allan deviation.
        adev_sigma: (3, m) its 1-sigma from the equivalent degrees of freedom.
        adev_fit: (3, m) the fitted model's deviation.
        fit_chi2: (3,) reduced chi-square of the fit (about 1 when the model fits).
    """

    sensor: str
    noise_density: Array
    random_walk: Array
    random_walk_fit: Array
    bias_instability: Array
    bias_instability_raw: Array
    bias_instability_fit: Array
    noise_density_sigma: Array
    random_walk_sigma: Array
    random_walk_resolved: NDArray[np.bool_]
    tau_at_minimum: Array
    tau: Array
    adev: Array
    adev_sigma: Array
    adev_fit: Array
    fit_chi2: Array

    @staticmethod
    def aggregate(values: Array, how: str) -> float | None:
        """Mean (``how="mean"``) or largest (``"max"``) of per-axis values; None if any is NaN."""
        if not np.all(np.isfinite(values)):
            return None
        return float(np.max(values) if how == "max" else np.mean(values))


@dataclass(frozen=True)
class AllanResult:
    """Noise model of an IMU from a static log.

    Attributes:
        gyroscope: gyro triad noise.
        accelerometer: accel triad noise.
        rate_hz: sample rate used.
        duration_s: length of the log.
        n_samples: number of samples.
        aggregate: how the Kalibr keys combine the axes (``"mean"`` or ``"max"``).
    """

    gyroscope: SensorNoise
    accelerometer: SensorNoise
    rate_hz: float
    duration_s: float
    n_samples: int
    aggregate: str = "mean"

    def to_dict(self) -> dict[str, Any]:
        """``kind``/``version``, Kalibr ``imu.yaml`` keys, bias instability per axis, per-axis
        values, the Allan curves and the fit quality (plain Python types, ready for YAML). A
        random walk that the log does not resolve is ``null`` with its reason under
        ``unobservable``."""
        out: dict[str, Any] = header(KIND, VERSION)
        unobservable: dict[str, str] = {}
        for s in (self.gyroscope, self.accelerometer):
            out[f"{s.sensor}_noise_density"] = s.aggregate(s.noise_density, self.aggregate)
            out[f"{s.sensor}_random_walk"] = s.aggregate(s.random_walk, self.aggregate)
            if out[f"{s.sensor}_random_walk"] is None:
                unobservable[f"{s.sensor}_random_walk"] = (
                    f"not resolved in a {self.duration_s / 3600:.2f} h log (the Allan "
                    "deviation does not turn upward clearly); record a longer static log")
        out["update_rate"] = float(self.rate_hz)
        for s in (self.gyroscope, self.accelerometer):
            out[f"{s.sensor}_bias_instability"] = s.bias_instability.tolist()
        out["aggregate"] = self.aggregate
        out["per_axis"] = {s.sensor: {
            "noise_density": s.noise_density.tolist(),
            "noise_density_sigma": s.noise_density_sigma.tolist(),
            "random_walk": [None if not np.isfinite(v) else float(v) for v in s.random_walk],
            "random_walk_fit": s.random_walk_fit.tolist(),
            "random_walk_sigma": s.random_walk_sigma.tolist(),
            "random_walk_resolved": [bool(v) for v in s.random_walk_resolved],
            "bias_instability": s.bias_instability.tolist(),
            "bias_instability_raw": s.bias_instability_raw.tolist(),
            "bias_instability_fit": s.bias_instability_fit.tolist(),
            "tau_at_minimum": s.tau_at_minimum.tolist(),
        } for s in (self.gyroscope, self.accelerometer)}
        out["allan"] = {s.sensor: {
            "tau": s.tau.tolist(),
            "adev": s.adev.tolist(),
            "adev_sigma": s.adev_sigma.tolist(),
            "adev_fit": s.adev_fit.tolist(),
        } for s in (self.gyroscope, self.accelerometer)}
        out["fit_quality"] = {s.sensor: {
            "model": "sigma^2 = N^2/tau + B^2 2ln2/pi + K^2 tau/3",
            "chi2": s.fit_chi2.tolist(),
        } for s in (self.gyroscope, self.accelerometer)}
        out["duration_s"] = float(self.duration_s)
        out["n_samples"] = int(self.n_samples)
        if unobservable:
            out["unobservable"] = unobservable
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> AllanResult:
        """Inverse of :meth:`to_dict`.

        Raises:
            KindError: another kind of file, or a newer version.
            ValueError, KeyError, TypeError: a missing or malformed entry.
        """
        check_kind(dict(d), KIND, VERSION, legacy=LEGACY_KEYS)
        sensors = {name: _sensor_from_dict(d, name) for name in ("gyroscope", "accelerometer")}
        return cls(sensors["gyroscope"], sensors["accelerometer"], float(d["update_rate"]),
                   float(d["duration_s"]), int(d["n_samples"]), str(d["aggregate"]))


def _floats(values: Any) -> Array:
    """Numbers (``None`` for NaN) as a float array."""
    return np.array([np.nan if v is None else float(v) for v in np.ravel(values)]).reshape(
        np.shape(values))


def _sensor_from_dict(d: Mapping[str, Any], sensor: str) -> SensorNoise:
    ax = d["per_axis"][sensor]
    cur = d["allan"][sensor]
    return SensorNoise(
        sensor=sensor,
        noise_density=_floats(ax["noise_density"]),
        random_walk=_floats(ax["random_walk"]),
        random_walk_fit=_floats(ax.get("random_walk_fit", ax["random_walk"])),
        bias_instability=_floats(ax["bias_instability"]),
        bias_instability_raw=_floats(ax["bias_instability_raw"]),
        bias_instability_fit=_floats(ax["bias_instability_fit"]),
        noise_density_sigma=_floats(ax["noise_density_sigma"]),
        random_walk_sigma=_floats(ax["random_walk_sigma"]),
        random_walk_resolved=np.array([bool(v) for v in ax["random_walk_resolved"]]),
        tau_at_minimum=_floats(ax["tau_at_minimum"]),
        tau=_floats(cur["tau"]),
        adev=_floats(cur["adev"]),
        adev_sigma=_floats(cur["adev_sigma"]),
        adev_fit=_floats(cur["adev_fit"]),
        fit_chi2=_floats(d["fit_quality"][sensor]["chi2"]),
    )
