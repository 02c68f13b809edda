"""What the mocap-free IMU commands (``multipos``, ``allan``, ``drift``) share: where the IMU
log comes from (the CLI's options) and a progress callback."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap_calib.core.model.rest import runs
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.params import param
from mocap_calib.core.prepare.fault_detection import dead_channels, describe_dead, frozen
from mocap_calib.errors import InputError
from mocap_calib.io.loader import load_imu_file
from mocap_calib.io.streams import Crop
from mocap_calib.workflows.session import (
    accel_unit_option,
    columns_option,
    gyro_unit_option,
    imu_topic_option,
    stamp_option,
    time_unit_option,
)

ProgressFn = Callable[[str], None]


def say(progress: ProgressFn | None, message: str) -> None:
    if progress is not None:
        progress(message)


@dataclass
class ImuSpec:
    """Where the IMU log comes from and how to read it (the IMU-only commands' input options;
    ``raw``, ``accel`` and ``gyro`` are ``multipos``'s)."""

    imu: Path | None = param(
        None, "IMU log: CSV (EuRoC imu0/data.csv layout, or generic with --columns), a mav0 "
        "folder, ROS 1 bag, ROS 2 bag folder (db3 or MCAP), .mcap, or PX4 .ulg",
        metavar="PATH", show_default=False)
    columns: str | None = columns_option()
    time_unit: str | None = time_unit_option()
    gyro_unit: str | None = gyro_unit_option()
    accel_unit: str | None = accel_unit_option()
    imu_topic: str | None = imu_topic_option()
    stamp: str = stamp_option()
    raw: bool = param(False, "the readings are raw sensor counts (e.g. a 16-bit MEMS part's "
                      "registers); results in SI units and in imu_tk's form", decls=("--raw",))
    accel: Path | None = param(
        None, "imu_tk's accelerometer file ('t ax ay az' per line, stamps in s unless "
        "--time-unit), with --gyro instead of --imu", metavar="PATH", decls=("--accel",),
        show_default=False)
    gyro: Path | None = param(None, "imu_tk's gyroscope file ('t gx gy gz' per line)",
                              metavar="PATH", decls=("--gyro",), show_default=False)


    def load(self, crop: CropSpec | None = None) -> tuple[ImuSamples, list[str]]:
        """Read the log (:func:`mocap_calib.io.loader.load_imu_file`), cut to ``crop`` before
        any check: samples and notes.

        Raises:
            InputError: also for a dead sensor or a frozen stretch (the same sample repeated),
                which the IMU-only tools cannot leave out (they need an unbroken log).
        """
        imu, notes = load_imu_file(self.imu, columns=self.columns, time_unit=self.time_unit,
                                   gyro_unit=self.gyro_unit, accel_unit=self.accel_unit,
                                   raw=self.raw, accel_file=self.accel, gyro_file=self.gyro,
                                   topic=self.imu_topic, stamp=self.stamp,
                                   crop=None if crop is None else Crop(crop.start, crop.end))
        refuse_faulty_log(imu)
        return imu, notes

    @property
    def name(self) -> str:
        """The input for progress lines."""
        if self.imu is None and (self.accel is not None or self.gyro is not None):
            return f"{self.accel} and {self.gyro}"
        return str(self.imu)


@dataclass
class CropSpec:
    """``--start``/``--end`` of the IMU-only commands that read a whole log."""

    start: float | None = param(
        None, "crop: keep the log from this many seconds after its first sample (before any "
        "check of the data)", unit="s", lo=0.0, show_default=False)
    end: float | None = param(
        None, "crop: keep the log up to this many seconds after its first sample (before any "
        "check of the data)", unit="s", lo=0.0, lo_open=True, show_default=False)


#: The options of ``multipos`` alone.
MULTIPOS_ONLY = ("raw", "accel", "gyro")


def refuse_faulty_log(imu: ImuSamples) -> None:
    """Raise for a dead channel or a frozen stretch of an IMU-only log (saturation is not
    judged here: at rest a quantised channel's extreme value repeats legitimately)."""
    dead = dead_channels(imu.gyro, imu.accel)
    if dead:
        raise InputError(f"{imu.source}: {describe_dead(imu.gyro, imu.accel, dead)}; check the "
                         "sensor and the column map")
    fz = frozen(np.hstack([imu.gyro, imu.accel]), imu.rate_hz or 1.0)
    if fz.any():
        spans = runs(fz, 1)
        first = float(imu.t[spans[0, 0]] - imu.t[0])
        raise InputError(
            f"{imu.source}: the IMU is frozen (the same sample repeated) for "
            f"{fz.sum() / imu.rate_hz:.3g} s in {len(spans)} stretch(es), the first at "
            f"{first:.1f} s; this tool needs an unbroken log: re-record, or cut the log to a "
            "stretch without them")
