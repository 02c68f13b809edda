"""Typed containers for the two input streams and the IMU noise model.

Times are float64 seconds since ``time_origin_ns`` (an integer nanosecond stamp on the stream's
own clock), so nanosecond stamps survive a read/write round trip and float times stay precise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3

Array = NDArray[np.float64]


def _as_float(a: object, shape_tail: tuple[int, ...]) -> Array:
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64))
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise ValueError(f"expected shape (N, {', '.join(map(str, shape_tail))}), got {arr.shape}")
    return arr


@dataclass(frozen=True)
class ImuSamples:
    """Raw IMU samples on the IMU clock.

    Attributes:
        t: (N,) seconds since ``time_origin_ns``.
        gyro: (N, 3) angular rate in rad/s, IMU frame.
        accel: (N, 3) specific force in m/s^2, IMU frame.
        time_origin_ns: integer stamp (ns) of ``t == 0`` on the IMU clock.
        source: where the samples came from, for messages.
    """

    t: Array
    gyro: Array
    accel: Array
    time_origin_ns: int = 0
    source: str = "imu"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", _as_float(self.t, ()))
        object.__setattr__(self, "gyro", _as_float(self.gyro, (3,)))
        object.__setattr__(self, "accel", _as_float(self.accel, (3,)))
        if not (len(self.t) == len(self.gyro) == len(self.accel)):
            raise ValueError("t, gyro and accel must have the same length")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0

    def stamps_ns(self) -> NDArray[np.int64]:
        """Integer nanosecond stamps on the IMU clock."""
        return self.time_origin_ns + np.round(self.t * 1e9).astype(np.int64)

    def select(self, mask: NDArray[np.bool_]) -> ImuSamples:
        return ImuSamples(self.t[mask], self.gyro[mask], self.accel[mask],
                          self.time_origin_ns, self.source)


@dataclass(frozen=True)
class MocapPoses:
    """Poses ``T_WM`` of the marker body measured by the motion-capture system.

    Attributes:
        t: (N,) seconds since ``time_origin_ns`` on the mocap clock.
        quat_wxyz: (N, 4) unit Hamilton quaternions of ``R_WM``.
        position: (N, 3) ``p_WM`` in metres.
        time_origin_ns: integer stamp (ns) of ``t == 0`` on the mocap clock.
        source: where the poses came from, for messages.
        dropped_rows: rows removed while reading (occlusions reported as NaN).
        position_unit_m: metres per unit of the numbers the positions were read from (1 for
            metres), so that a check can say which unit the data fit.
    """

    t: Array
    quat_wxyz: Array
    position: Array
    time_origin_ns: int = 0
    source: str = "mocap"
    dropped_rows: int = 0
    position_unit_m: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", _as_float(self.t, ()))
        object.__setattr__(self, "quat_wxyz", _as_float(self.quat_wxyz, (4,)))
        object.__setattr__(self, "position", _as_float(self.position, (3,)))
        if not (len(self.t) == len(self.quat_wxyz) == len(self.position)):
            raise ValueError("t, quat_wxyz and position must have the same length")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0

    @property
    def rotation(self) -> Array:
        """(N, 3, 3) rotation matrices ``R_WM``."""
        return so3.quat_to_rotmat(self.quat_wxyz)

    def stamps_ns(self) -> NDArray[np.int64]:
        return self.time_origin_ns + np.round(self.t * 1e9).astype(np.int64)

    def select(self, mask: NDArray[np.bool_]) -> MocapPoses:
        return MocapPoses(self.t[mask], self.quat_wxyz[mask], self.position[mask],
                          self.time_origin_ns, self.source, self.dropped_rows,
                          self.position_unit_m)


@dataclass(frozen=True)
class NoiseModel:
    """Continuous-time IMU noise (Kalibr ``imu.yaml`` units) and mocap noise.

    Defaults are EuRoC's ADIS16448 values and a typical Vicon room.
    """

    gyroscope_noise_density: float = 1.6968e-04  # rad/s/sqrt(Hz)
    gyroscope_random_walk: float = 1.9393e-05  # rad/s^2/sqrt(Hz)
    accelerometer_noise_density: float = 2.0e-3  # m/s^2/sqrt(Hz)
    accelerometer_random_walk: float = 3.0e-3  # m/s^3/sqrt(Hz)
    mocap_position_sigma: float = 0.5e-3  # m, per axis and sample
    mocap_rotation_sigma: float = float(np.radians(0.05))  # rad, per axis and sample
    # Real mocap noise is correlated over time (marker sets change, the pose solver and its
    # filters smooth): a fraction of its variance is an AR(1) process with this time constant.
    mocap_noise_corr_time: float = 0.0  # s; 0: white
    mocap_noise_corr_fraction: float = 0.0  # fraction of the variance that is correlated
    # The accelerometer's white-noise variance per IMU axis, as factors on its density's square
    # (a drone's vibration is strongest along the thrust axis); all ones: the same on each.
    accelerometer_axis_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @property
    def isotropic(self) -> bool:
        return tuple(self.accelerometer_axis_scale) == (1.0, 1.0, 1.0)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the per-axis factors only when they are not all one)."""
        out: dict[str, Any] = {k: float(v) for k, v in self.__dict__.items()
                               if k != "accelerometer_axis_scale"}
        if not self.isotropic:
            out["accelerometer_axis_scale"] = [float(x) for x in self.accelerometer_axis_scale]
        return out

    def imu_scaled(self, f: float) -> NoiseModel:
        """This model with the IMU noise densities and random walks times ``f`` (the noise
        sensitivity's x3 and x1/3)."""
        return replace(self, gyroscope_noise_density=self.gyroscope_noise_density * f,
                       gyroscope_random_walk=self.gyroscope_random_walk * f,
                       accelerometer_noise_density=self.accelerometer_noise_density * f,
                       accelerometer_random_walk=self.accelerometer_random_walk * f)

    @property
    def mocap_correlated(self) -> bool:
        return self.mocap_noise_corr_time > 0.0 and self.mocap_noise_corr_fraction > 0.0

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NoiseModel:
        known: dict[str, Any] = {k: float(v) for k, v in d.items()
                                 if k in cls.__dataclass_fields__
                                 and k != "accelerometer_axis_scale"}
        if d.get("accelerometer_axis_scale") is not None:
            known["accelerometer_axis_scale"] = tuple(
                float(x) for x in d["accelerometer_axis_scale"])
        return cls(**known)
