"""The two streams as readers hand them over, before any check: :class:`ImuTable` and
:class:`PoseTable`, their ``--start``/``--end`` crop and their validation.

Every reader returns tables; the loader crops them and only then validates them
(:mod:`mocap_calib.io.validate`), so that no check refuses rows the user cropped away. A cropped
stream keeps its uncropped origin (the log's first sample), so times and stamps read the same as
those of the whole log.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError
from mocap_calib.io.validate import Lines, imu_gap_note, validate_imu, validate_mocap

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Fewest IMU samples a cropped part may keep (as the crop of ``core/prepare/crop.py``).
MIN_CROPPED_SAMPLES = 100


@dataclass(frozen=True)
class ImuTable:
    """IMU samples as read: integer nanosecond stamps in file order, gyro in rad/s and
    accelerometer in m/s^2 (raw counts with ``raw``), not yet checked.

    Attributes:
        ns: (N,) stamps.
        gyro: (N, 3).
        accel: (N, 3).
        lines: Where the rows came from (the samples' ``source``).
        time_unit: The unit the stamps were declared in (for the checks' hints).
        gyro_unit: The gyro's declared unit (for hints).
        accel_unit: The accelerometer's declared unit (for hints).
        raw: The readings are raw counts (no unit check).
        note_gaps: Note the gaps of the stamps (the recording readers do: their logs drop
            messages).
        file: The file named in the ``IMU: ...`` note (None: the path given).
        last_notes: Notes that follow the gap note (a logger's own dropout records).
        origin_ns: The stamp of ``t == 0`` (None: the first stamp); set by the crop.
    """

    ns: IntArray
    gyro: Array
    accel: Array
    lines: Lines
    time_unit: str = "ns"
    gyro_unit: str = "rad/s"
    accel_unit: str = "m/s^2"
    raw: bool = False
    note_gaps: bool = False
    file: str | None = None
    last_notes: tuple[str, ...] = ()
    origin_ns: int | None = None

    def __len__(self) -> int:
        return len(self.ns)

    def take(self, rows: IntArray) -> ImuTable:
        return replace(self, ns=self.ns[rows], gyro=self.gyro[rows], accel=self.accel[rows],
                       lines=self.lines.subset(rows))

    def validate(self) -> ImuSamples:
        """The checked samples (:func:`~mocap_calib.io.validate.validate_imu`)."""
        return validate_imu(self.ns, self.gyro, self.accel, self.lines,
                            time_unit=self.time_unit, gyro_unit=self.gyro_unit,
                            accel_unit=self.accel_unit, raw=self.raw, origin_ns=self.origin_ns)

    def notes(self, imu: ImuSamples) -> list[str]:
        """The reader's notes on the checked samples: gaps, then the last notes."""
        gaps = imu_gap_note(imu.t, self.lines.source) if self.note_gaps else None
        return [*([gaps] if gaps is not None else []), *self.last_notes]


@dataclass(frozen=True)
class PoseTable:
    """Mocap poses ``T_WM`` as read: integer nanosecond stamps in file order, quaternions
    ``[w, x, y, z]`` (NaN rows: occlusions), positions in metres, not yet checked.

    Attributes:
        ns: (N,) stamps.
        quat_wxyz: (N, 4).
        position: (N, 3).
        lines: Where the rows came from (the poses' ``source``).
        time_unit: The unit the stamps were declared in (for hints).
        position_unit: The positions' declared unit (for hints).
        file: The file named in the ``mocap: ...`` note (None: the path given).
        origin_ns: The stamp of ``t == 0`` (None: the first complete pose's).
    """

    ns: IntArray
    quat_wxyz: Array
    position: Array
    lines: Lines
    time_unit: str = "ns"
    position_unit: str = "m"
    file: str | None = None
    origin_ns: int | None = None

    def __len__(self) -> int:
        return len(self.ns)

    def take(self, rows: IntArray) -> PoseTable:
        return replace(self, ns=self.ns[rows], quat_wxyz=self.quat_wxyz[rows],
                       position=self.position[rows], lines=self.lines.subset(rows))

    def complete(self) -> NDArray[np.bool_]:
        """Rows with no NaN (the poses the checks keep)."""
        return ~(np.isnan(self.quat_wxyz).any(axis=1) | np.isnan(self.position).any(axis=1))

    def validate(self) -> MocapPoses:
        """The checked poses (:func:`~mocap_calib.io.validate.validate_mocap`)."""
        return validate_mocap(self.ns, self.quat_wxyz, self.position, self.lines,
                              time_unit=self.time_unit, position_unit=self.position_unit,
                              origin_ns=self.origin_ns)


@dataclass(frozen=True)
class Crop:
    """``--start``/``--end``: seconds after the IMU log's first sample; the mocap is cut to
    match with ``margin_s`` on each side (for the clock offset) when both streams' stamps share
    an epoch."""

    start: float | None = None
    end: float | None = None
    margin_s: float = 1.0

    @property
    def given(self) -> bool:
        return self.start is not None or self.end is not None

    def bounds(self) -> tuple[float, float]:
        """(lo, hi) in seconds from the first IMU sample."""
        lo = self.start or 0.0
        hi = self.end if self.end is not None else np.inf
        if not hi > lo:
            raise InputError(f"--end {self.end:g} must be after --start {lo:g}")
        return lo, hi


def crop_imu_table(table: ImuTable, crop: Crop | None) -> ImuTable:
    """The rows from ``crop.start`` to ``crop.end`` (s after the first row's stamp)."""
    if crop is None or not crop.given or len(table) == 0:
        return table
    lo, hi = crop.bounds()
    origin = int(table.ns[0])
    t = (table.ns - origin) / 1e9
    rows = np.flatnonzero((t >= lo) & (t <= hi))
    if len(rows) < MIN_CROPPED_SAMPLES:
        given = " ".join(f"--{k} {v:g}" for k, v in (("start", crop.start), ("end", crop.end))
                         if v is not None)
        left = ("nothing of the session is left" if len(rows) < 2
                else f"only {len(rows)} IMU samples are left")
        span = float(t[-1] - t[0])
        raise InputError(f"{table.lines.source}: {given}: {left} (the IMU log spans 0 to "
                         f"{span:.1f} s from its first sample); choose --start/--end within it")
    return replace(table.take(rows), origin_ns=origin)


def crop_pose_table(table: PoseTable, crop: Crop | None, imu_first_ns: int,
                    imu_last_ns: int) -> PoseTable:
    """The poses within the crop (with its margin), on the IMU's time axis, when the two
    streams' stamps share an epoch; from clocks of different epochs the poses stay whole (the
    clock search finds the matching stretch)."""
    if crop is None or not crop.given or len(table) == 0:
        return table
    complete = np.flatnonzero(table.complete())
    if len(complete) == 0:
        return table
    origin = int(table.ns[complete[0]])
    # The same arithmetic as on the checked streams: mocap seconds moved onto the IMU axis.
    shift = (imu_first_ns - origin) * 1e-9
    tm = (table.ns - origin) / 1e9 - shift
    imu_end = (imu_last_ns - imu_first_ns) / 1e9
    if tm[complete[-1]] < 0.0 or tm[complete[0]] > imu_end:  # different epochs
        return table
    lo, hi = crop.bounds()
    rows = np.flatnonzero((tm >= lo - crop.margin_s) & (tm <= hi + crop.margin_s))
    return replace(table.take(rows), origin_ns=origin)
