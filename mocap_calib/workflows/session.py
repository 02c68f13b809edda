"""Reading a session for the commands that need both streams: input spec, noise, priors."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.policy import GRAVITY  # noqa: F401  (the CLI's default)
from mocap_calib.core.result.priors import priors_from_results
from mocap_calib.errors import InputError
from mocap_calib.io.formats.bags import RecordingOptions
from mocap_calib.io.formats.mocap_exports import ExportOptions
from mocap_calib.io.loader import load_inputs
from mocap_calib.io.yaml_io import load_noise, load_result


@dataclass
class InputSpec:
    """Where the two streams come from and how to read them."""

    path: Path | None = None
    imu: Path | None = None
    mocap: Path | None = None
    pose_source: str = "auto"
    columns: str | None = None
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    quat_order: str | None = None
    position_unit: str | None = None
    # Bags and ULogs (io.bags / io.ulog).
    imu_topic: str | None = None
    mocap_topic: str | None = None
    mocap_frame: str | None = None
    stamp: str = "header"
    # Motive / Vicon exports (io.mocap_exports).
    mocap_format: str | None = None
    rigid_body: str | None = None
    rotation: str | None = None
    mocap_rate: float | None = None

    def recording(self) -> RecordingOptions:
        return RecordingOptions(self.imu_topic, self.mocap_topic, self.mocap_frame, self.stamp)

    def export(self) -> ExportOptions:
        return ExportOptions(self.mocap_format, self.rigid_body, self.rotation, self.mocap_rate)


@dataclass
class LoadedSession:
    imu: ImuSamples
    mocap: MocapPoses
    notes: list[str] = field(default_factory=list)
    sensor_noise: NoiseModel | None = None


def load_session(spec: InputSpec) -> LoadedSession:
    """Read both streams (and, from a ``mav0`` folder, the IMU's ``sensor.yaml`` noise)."""
    if spec.path is None and (spec.imu is None or spec.mocap is None):
        raise InputError("give a mav0 folder, or both --imu and --mocap")
    if spec.path is not None and (spec.imu is not None or spec.mocap is not None):
        raise InputError("give either a mav0 folder or --imu/--mocap, not both")
    imu, mocap, notes = load_inputs(
        spec.imu, spec.mocap, spec.path, pose_source=spec.pose_source, columns=spec.columns,
        time_unit=spec.time_unit, gyro_unit=spec.gyro_unit, accel_unit=spec.accel_unit,
        quat_order=spec.quat_order, position_unit=spec.position_unit,
        recording=spec.recording(), export=spec.export())
    sensor_noise = None
    if spec.path is not None:
        from mocap_calib.io.formats.euroc import find_mav0

        root = find_mav0(spec.path)
        sensor = root / "imu0" / "sensor.yaml"
        if sensor.is_file():
            try:
                sensor_noise = load_noise(sensor)
                notes.append(f"noise densities from {sensor}")
            except InputError:
                sensor_noise = None
    return LoadedSession(imu, mocap, notes, sensor_noise)


def resolve_noise(session: LoadedSession, noise_file: Path | None,
                  overrides: dict[str, float | None]) -> NoiseModel:
    """Noise model: defaults < the mav0's ``imu0/sensor.yaml`` < ``--noise`` file < options."""
    noise = session.sensor_noise or NoiseModel()
    if noise_file is not None:
        noise = load_noise(noise_file, noise)
    given = {k: v for k, v in overrides.items() if v is not None}
    for k, v in given.items():
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"noise option {k.replace('_', '-')} must be positive, got {v}")
    return replace(noise, **given) if given else noise


def load_priors(paths: list[Path], at_ns: int) -> list:
    """Prior factors from one or more earlier results (a trend with two or more)."""
    results = [load_result(p) for p in paths]
    return priors_from_results(results, at_ns if len(results) > 1 else None)
