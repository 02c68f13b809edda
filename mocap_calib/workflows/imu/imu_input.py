"""What the mocap-free IMU commands (``multipos``, ``allan``, ``drift``) share: where the IMU
log comes from (the CLI's options) and a progress callback."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap_calib.core.model.faults import dead_channels, describe_dead, frozen
from mocap_calib.core.model.rest import runs
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import InputError
from mocap_calib.io.loader import load_imu_file

ProgressFn = Callable[[str], None]


def say(progress: ProgressFn | None, message: str) -> None:
    if progress is not None:
        progress(message)


@dataclass
class ImuSpec:
    """Where the IMU log comes from and how to read it (options of ``cli/common.py``).

    Attributes:
        imu: EuRoC ``imu0/data.csv``, a ``mav0`` folder (or its parent), or a generic CSV.
        columns: column map of a generic CSV (``--columns``).
        time_unit: s, ms, us or ns; None for the format's own.
        gyro_unit: rad/s or deg/s; None for the format's own.
        accel_unit: m/s^2 or g; None for the format's own.
        imu_topic: bags and ULogs: the IMU topic (``--imu-topic``).
        stamp: bags: ``header`` or ``receive`` stamps (``--stamp``).
        raw: the readings are raw sensor counts (``--raw``).
        accel: imu_tk's accelerometer file (``--accel``), with ``gyro``.
        gyro: imu_tk's gyroscope file (``--gyro``).
    """

    imu: Path | None = None
    columns: str | None = None
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    imu_topic: str | None = None
    stamp: str = "header"
    raw: bool = False
    accel: Path | None = None
    gyro: Path | None = None

    def load(self) -> tuple[ImuSamples, list[str]]:
        """Read the log (:func:`mocap_calib.io.loader.load_imu_file`): samples and notes.

        Raises:
            InputError: also for a dead sensor or a frozen stretch (the same sample repeated),
                which the IMU-only tools cannot leave out (they need an unbroken log).
        """
        imu, notes = load_imu_file(self.imu, columns=self.columns, time_unit=self.time_unit,
                                   gyro_unit=self.gyro_unit, accel_unit=self.accel_unit,
                                   raw=self.raw, accel_file=self.accel, gyro_file=self.gyro,
                                   topic=self.imu_topic, stamp=self.stamp)
        refuse_faulty_log(imu)
        return imu, notes

    @property
    def name(self) -> str:
        """The input for progress lines."""
        if self.imu is None and (self.accel is not None or self.gyro is not None):
            return f"{self.accel} and {self.gyro}"
        return str(self.imu)


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
