"""Reading a session for the commands that need both streams: the input spec (every input
option of ``calibrate``, shared by ``diagnose``, ``groundtruth`` and ``batch``), the noise
options, priors, and the part of the session to use."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.params import ParamInfo, check_value, group, param, param_info
from mocap_calib.core.plausible import PlausibleLimits
from mocap_calib.core.result.priors import prior_problems, priors_from_results
from mocap_calib.errors import InputError
from mocap_calib.io.formats.euroc import find_mav0
from mocap_calib.io.loader import load_inputs
from mocap_calib.io.reading import ExportOptions, RecordingOptions
from mocap_calib.io.streams import Crop
from mocap_calib.io.validate import MIN_MOCAP_RATE_HZ
from mocap_calib.io.yaml_io import load_noise, load_result, noise_values

#: The format options shared with the IMU-only commands (same names, same help).
COLUMNS_HELP = ("column map of a generic CSV, e.g. 't=0,gyro=1:4,accel=4:7,quat=10:14,"
                "pos=14:17', or a preset name ('broad')")
TIME_UNITS = ("s", "ms", "us", "ns")
GYRO_UNITS = ("rad/s", "deg/s")
ACCEL_UNITS = ("m/s^2", "g")
STAMPS = ("header", "receive")
IMU_TOPIC_HELP = ("IMU topic of a bag or ULog (sensor_msgs/Imu; ULog: sensor_combined, or one "
                  "IMU of several as sensor_gyro:N or sensor_accel:N), or the IMU's events of a "
                  "Crazyflie uSD log (GYRO_EVENT,ACCEL_EVENT, or one event holding both); "
                  "default: the only one (ULog: sensor_combined; Crazyflie: "
                  "estGyroscope,estAcceleration)")


@dataclass
class MocapFormat:
    """How to read the mocap poses (shared with ``drift --mocap``)."""

    quat_order: str | None = param(None, "quaternion order of the mocap file",
                                   choices=("wxyz", "xyzw"), show_default=False)
    position_unit: str | None = param(None, "position unit of the mocap file",
                                      choices=("m", "cm", "mm"), show_default=False)
    mocap_topic: str | None = param(
        None, "pose topic of a bag or ULog (PoseStamped, TransformStamped, "
        "PoseWithCovarianceStamped, Odometry, or /tf with --mocap-frame; ULog: "
        "vehicle_mocap_odometry or vehicle_visual_odometry), or the pose event of a Crazyflie "
        "uSD log; default: the only one (Crazyflie: estPose)", show_default=False)
    mocap_frame: str | None = param(
        None, "the marker body's frame in a tf2_msgs/TFMessage topic: CHILD (its pose in the root "
        "of its TF tree, /tf_static included) or PARENT:CHILD (in PARENT)", show_default=False)
    mocap_format: str | None = param(
        None, "mocap export format (default: detected from the header)",
        choices=("motive", "vicon-nexus", "vicon-tracker"), show_default=False)
    rigid_body: str | None = param(None, "rigid body (Motive) or subject (Vicon) to read when "
                                   "the export holds several", show_default=False)
    rotation: str | None = param(
        None, "Vicon rotations: helical or euler-xyz (R = Rx Ry Rz), optionally :deg or :rad; "
        "the file does not say which", show_default=False)
    mocap_rate: float | None = param(None, "mocap frame rate, for exports without one "
                                     "(frame numbers only)", unit="Hz", lo=0.0, lo_open=True,
                                     show_default=False)


# How the IMU log is read: one declaration each, for every request that reads one.
def columns_option() -> Any:
    return param(None, COLUMNS_HELP, show_default=False)


def time_unit_option() -> Any:
    return param(None, "time-stamp unit (default: the format's own)", choices=TIME_UNITS,
                 show_default=False)


def gyro_unit_option() -> Any:
    return param(None, "gyro unit (default: the format's own)", choices=GYRO_UNITS,
                 show_default=False)


def accel_unit_option() -> Any:
    return param(None, "accelerometer unit (default: the format's own)", choices=ACCEL_UNITS,
                 show_default=False)


def imu_topic_option() -> Any:
    return param(None, IMU_TOPIC_HELP, show_default=False)


def stamp_option() -> Any:
    return param("header", "bag stamps: header (message header.stamp) or receive (the bag's "
                 "record time)", choices=STAMPS)


@dataclass
class InputSpec:
    """Where the two streams come from and how to read them."""

    mav0: tuple[Path, ...] = param(
        (), "EuRoC/ASL mav0 folder (or its parent) holding imu0/ and vicon0/ (or "
        "state_groundtruth_estimate0/)", argument=True, metavar="MAV0", show_default=False)
    imu: tuple[Path, ...] = param(
        (), "IMU log: CSV (EuRoC imu0/data.csv layout, or generic with --columns), ROS 1 bag, "
        "ROS 2 bag folder (db3 or MCAP), .mcap, or PX4 .ulg", metavar="PATH",
        show_default=False)
    mocap: tuple[Path, ...] = param(
        (), "mocap poses T_WM: EuRoC vicon0/data.csv, TUM, generic CSV with --columns, Motive "
        "or Vicon CSV export, a bag/.mcap/.ulg; may be the same file as --imu", metavar="PATH",
        show_default=False)
    start: float | None = param(
        None, "crop: keep the session from this many seconds after the IMU log's first "
        "sample (before any check of the data)", unit="s", lo=0.0, show_default=False)
    end: float | None = param(
        None, "crop: keep the session up to this many seconds after the IMU log's first "
        "sample (before any check of the data)", unit="s", lo=0.0, lo_open=True,
        show_default=False)
    pose_source: str = param("auto", "with a mav0 folder: which poses to read (auto: vicon0 if "
                             "present)", choices=("auto", "vicon0", "groundtruth"))
    columns: str | None = param(None, COLUMNS_HELP + "; covers both files",
                                show_default=False)
    imu_columns: str | None = param(
        None, "column map of the IMU file alone (t=, gyro=, accel=), when the two files differ "
        "in layout; not with --columns", show_default=False)
    mocap_columns: str | None = param(
        None, "column map of the mocap file alone (t=, quat=, pos=), when the two files "
        "differ in layout; not with --columns", show_default=False)
    time_unit: str | None = time_unit_option()
    gyro_unit: str | None = gyro_unit_option()
    accel_unit: str | None = accel_unit_option()
    imu_topic: str | None = imu_topic_option()
    stamp: str = stamp_option()
    poses: MocapFormat = group(MocapFormat, "Input")

    def __post_init__(self) -> None:
        # The Python API may pass one path where the command line allows several.
        for name in ("mav0", "imu", "mocap"):
            value = getattr(self, name)
            if isinstance(value, (str, Path)):
                setattr(self, name, (Path(value),))

    def recording(self) -> RecordingOptions:
        return RecordingOptions(self.imu_topic, self.poses.mocap_topic, self.poses.mocap_frame,
                                self.stamp)

    def export(self) -> ExportOptions:
        p = self.poses
        return ExportOptions(p.mocap_format, p.rigid_body, p.rotation, p.mocap_rate)

    def crop(self, time_offset: float | None = None) -> Crop | None:
        """``--start``/``--end``, the mocap kept 1 s (plus the clock offset) beyond them."""
        if self.start is None and self.end is None:
            return None
        margin = 1.0 if time_offset is None else 1.0 + abs(time_offset)
        return Crop(self.start, self.end, margin)

    def sources(self) -> list[Path]:
        """Every input path given (for reports' provenance)."""
        return [*self.mav0, *self.imu, *self.mocap]

    def takes(self) -> list[InputSpec]:
        """One spec per take: several mav0 folders, or --imu/--mocap pairs in order (one
        recording: itself). Unequal numbers of --imu and --mocap are refused."""
        if self.mav0 and (self.imu or self.mocap):
            raise InputError("give either mav0 folders or --imu/--mocap, not both")
        if self.mav0:
            return [replace(self, mav0=(m,)) for m in self.mav0]
        if len(self.imu) != len(self.mocap):
            raise InputError(
                f"{len(self.imu)} --imu and {len(self.mocap)} --mocap given; several takes are "
                "given as pairs, in order: --imu A --mocap A --imu B --mocap B (the same file "
                "twice when one file holds both streams)")
        return [replace(self, imu=(i,), mocap=(m,))
                for i, m in zip(self.imu, self.mocap, strict=True)] or [self]

    def single(self) -> tuple[Path | None, Path | None, Path | None]:
        """(mav0, imu, mocap) of the one recording this command reads; refuses several."""
        if len(self.mav0) > 1 or len(self.imu) > 1 or len(self.mocap) > 1:
            raise InputError(
                f"{max(len(self.mav0), len(self.imu), len(self.mocap))} recordings given (a "
                "mav0 folder or --imu/--mocap more than once); this command reads one: give "
                "each option once")
        return (self.mav0[0] if self.mav0 else None, self.imu[0] if self.imu else None,
                self.mocap[0] if self.mocap else None)


@dataclass
class NoiseSpec:
    """The noise model: a file and single values over it (defaults < the mav0's
    ``imu0/sensor.yaml`` < ``--noise`` file < these options)."""

    noise: Path | None = param(
        None, "noise model YAML (Kalibr imu.yaml keys, e.g. from 'mocap-calib allan'); "
        "default: the mav0's imu0/sensor.yaml, else EuRoC ADIS16448 values", metavar="PATH",
        show_default=False)
    gyro_noise: float | None = param(None, "gyro noise density", unit="rad/s/sqrt(Hz)",
                                     lo=0.0, lo_open=True, hi=1.0, show_default=False)
    gyro_walk: float | None = param(None, "gyro bias random walk", unit="rad/s^2/sqrt(Hz)",
                                    lo=0.0, lo_open=True, hi=1.0, show_default=False)
    accel_noise: float | None = param(None, "accel noise density", unit="m/s^2/sqrt(Hz)",
                                      lo=0.0, lo_open=True, hi=10.0, show_default=False)
    accel_walk: float | None = param(None, "accel bias random walk", unit="m/s^3/sqrt(Hz)",
                                     lo=0.0, lo_open=True, hi=10.0, show_default=False)
    mocap_noise_mm: float | None = param(None, "mocap position noise per axis (default 0.5)",
                                         unit="mm", lo=0.0, lo_open=True, hi=100.0,
                                         show_default=False)
    mocap_noise_deg: float | None = param(None, "mocap attitude noise per axis (default 0.05)",
                                          unit="deg", lo=0.0, lo_open=True, hi=10.0,
                                          show_default=False)

    #: A noise file's keys: the option that sets the same value and the value in that
    #: option's unit (the file's are SI).
    FILE_KEYS: ClassVar[dict[str, tuple[str, Callable[[float], float]]]] = {
        "gyroscope_noise_density": ("gyro_noise", float),
        "gyroscope_random_walk": ("gyro_walk", float),
        "accelerometer_noise_density": ("accel_noise", float),
        "accelerometer_random_walk": ("accel_walk", float),
        "mocap_position_sigma": ("mocap_noise_mm", lambda m: 1e3 * m),
        "mocap_rotation_sigma": ("mocap_noise_deg", lambda rad: float(np.degrees(rad))),
    }

    def overrides(self) -> dict[str, float]:
        """The noise-model fields given as options, in SI units."""
        given = {
            "gyroscope_noise_density": self.gyro_noise,
            "gyroscope_random_walk": self.gyro_walk,
            "accelerometer_noise_density": self.accel_noise,
            "accelerometer_random_walk": self.accel_walk,
            "mocap_position_sigma": None if self.mocap_noise_mm is None
            else self.mocap_noise_mm * 1e-3,
            "mocap_rotation_sigma": None if self.mocap_noise_deg is None
            else float(np.radians(self.mocap_noise_deg)),
        }
        return {k: v for k, v in given.items() if v is not None}

    def resolve(self, base: NoiseModel | None, base_source: str | None = None) -> NoiseModel:
        """The noise model: ``base`` (or the defaults) < the file < the options. The values
        read from a file (the ``--noise`` file; ``base`` when ``base_source`` names the file
        it came from) must be within the options' ranges (:meth:`check_values`)."""
        if base is not None and base_source is not None:
            self.check_values(base.to_dict(), base_source)
        noise = base or NoiseModel()
        if self.noise is not None:
            noise = load_noise(self.noise, noise)
            self.check_values(noise_values(self.noise), str(self.noise))
        given = self.overrides()
        return replace(noise, **given) if given else noise

    @staticmethod
    def sensor_file(inputs: InputSpec) -> str | None:
        """The first take's mav0 ``imu0/sensor.yaml`` (the base noise it gives), if any."""
        mav0 = inputs.takes()[0].mav0
        try:
            return str(find_mav0(mav0[0]) / "imu0" / "sensor.yaml") if mav0 else None
        except InputError:
            return None

    @classmethod
    def check_values(cls, values: dict[str, float], source: str) -> None:
        """Each noise value read from ``source`` within the range of the option that sets the
        same value (``gyroscope_noise_density`` as ``--gyro-noise``, ...): a file is no
        licence for what the command line refuses.

        Raises:
            InputError: naming the file, the key, the value and the range.
        """
        infos = {f.name: param_info(f) for f in fields(cls)}
        for key, value in values.items():
            if key not in cls.FILE_KEYS or value is None:
                continue
            name, in_option_unit = cls.FILE_KEYS[key]
            info = infos[name]
            assert info is not None
            try:
                check_value(name, in_option_unit(float(value)), info)
            except InputError:
                raise InputError(f"{source}: '{key}' is {float(value):g}; it must be "
                                 f"{cls._in_file_units(info, in_option_unit)} (the range of "
                                 f"{info.option_name(name)}); fix the noise values") from None

    @staticmethod
    def _in_file_units(info: ParamInfo, in_option_unit: Callable[[float], float]) -> str:
        """An option's range said in the file's SI units (mm -> m, deg -> rad)."""
        scale = in_option_unit(1.0)
        if scale == 1.0:
            return info.allowed()
        lo = None if info.lo is None else info.lo / scale
        hi = None if info.hi is None else info.hi / scale
        unit = {"mm": "m", "deg": "rad"}.get(info.unit or "", info.unit)
        return replace(info, lo=lo, hi=hi, unit=unit).allowed()


@dataclass
class LoadedSession:
    imu: ImuSamples
    mocap: MocapPoses
    notes: list[str] = field(default_factory=list)
    sensor_noise: NoiseModel | None = None


def load_session(spec: InputSpec, time_offset: float | None = None) -> LoadedSession:
    """Read both streams (and, from a ``mav0`` folder, the IMU's ``sensor.yaml`` noise), cut
    to ``--start``/``--end`` before any check looks at them (the mocap with a margin of 1 s
    plus ``time_offset``)."""
    path, imu_path, mocap_path = spec.single()
    if path is None and (imu_path is None or mocap_path is None):
        raise InputError("give a mav0 folder, or both --imu and --mocap")
    if path is not None and (imu_path is not None or mocap_path is not None):
        raise InputError("give either a mav0 folder or --imu/--mocap, not both")
    imu, mocap, notes = load_inputs(
        imu_path, mocap_path, path, pose_source=spec.pose_source, columns=spec.columns,
        imu_columns=spec.imu_columns, mocap_columns=spec.mocap_columns,
        time_unit=spec.time_unit, gyro_unit=spec.gyro_unit, accel_unit=spec.accel_unit,
        quat_order=spec.poses.quat_order, position_unit=spec.poses.position_unit,
        recording=spec.recording(), export=spec.export(), crop=spec.crop(time_offset),
        min_mocap_rate_hz=MIN_MOCAP_RATE_HZ)
    sensor_noise = None
    if path is not None:
        sensor = find_mav0(path) / "imu0" / "sensor.yaml"
        if sensor.is_file():
            try:
                sensor_noise = load_noise(sensor)
                notes.append(f"noise densities from {sensor}")
            except InputError:
                sensor_noise = None
    return LoadedSession(imu, mocap, notes, sensor_noise)


def load_priors(paths: list[Path] | tuple[Path, ...], at_ns: int,
                limits: PlausibleLimits | None = None) -> list:
    """Prior factors from one or more earlier results (a trend with two or more).

    Raises:
        InputError: a file that is not a result, or whose values cannot be a prior: not finite,
            beyond the plausibility ``limits`` (default: the defaults), sigmas that are not
            positive, a rotation that is no quaternion (:func:`prior_problems`).
    """
    results = [load_result(p) for p in paths]
    for p, r in zip(paths, results, strict=True):
        problems = prior_problems(r, limits or PlausibleLimits())
        if problems:
            raise InputError(f"{p}: as a --prior, {problems[0]}; give the result of a "
                             "calibration that passed its checks")
    sources = tuple(str(p) for p in paths)
    return [replace(pr, sources=sources)
            for pr in priors_from_results(results, at_ns if len(results) > 1 else None)]
