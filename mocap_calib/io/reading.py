"""What every reader is given and what every format declares: the user's reading options
(:class:`ReadOptions`) and the format record (:class:`Format`) of the registry
(:mod:`mocap_calib.io.registry`).

A format says how to recognise it by content (``sniff``), how to read each stream it can hold
(functions taking the path, the options and the notes list, returning the stream's table,
:mod:`mocap_calib.io.streams`) and which options it uses. The loader refuses or notes, in one
place (:func:`screen`), every option given that the format of a file cannot use.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mocap_calib.errors import input_error
from mocap_calib.io.formats.columns import ColumnMap
from mocap_calib.io.streams import Crop, ImuTable, PoseTable


class Stream(enum.Enum):
    IMU = "IMU"
    POSES = "mocap"


@dataclass(frozen=True)
class RecordingOptions:
    """How to read bags and flight logs: topics (or events), the TF child frame and the stamp
    source.

    Attributes:
        imu_topic: IMU topic (None: the only ``sensor_msgs/Imu`` topic; ULog:
            ``sensor_combined``, or ``sensor_gyro:N`` / ``sensor_accel:N`` for one IMU; a
            Crazyflie uSD log: ``GYRO_EVENT,ACCEL_EVENT``).
        mocap_topic: pose topic or event (None: the only pose topic, ``/tf`` last; ``estPose``).
        mocap_frame: the marker body's frame in a ``TFMessage`` topic: ``CHILD`` (posed in the
            root of its TF tree) or ``PARENT:CHILD``.
        stamp: ``header`` (message header stamps) or ``receive`` (the bag's record time).
    """

    imu_topic: str | None = None
    mocap_topic: str | None = None
    mocap_frame: str | None = None
    stamp: str = "header"


@dataclass(frozen=True)
class ExportOptions:
    """How to read a mocap export.

    Attributes:
        mocap_format: motive, vicon-nexus, vicon-tracker, or None to detect it.
        rigid_body: the rigid body / subject to read when the file holds several.
        rotation: Vicon rotation form, ``helical`` or ``euler-xyz`` (optionally ``:deg``/``:rad``).
        mocap_rate: frame rate (Hz) for files without one.
    """

    mocap_format: str | None = None
    rigid_body: str | None = None
    rotation: str | None = None
    mocap_rate: float | None = None


#: Unit options, in the order notes list them; None means the format's own unit.
UNIT_OPTIONS = ("time_unit", "gyro_unit", "accel_unit", "quat_order", "position_unit")
#: The options of each stream's file (names of :class:`ReadOptions` fields or of its parts).
STREAM_OPTIONS: dict[Stream, tuple[str, ...]] = {
    Stream.IMU: ("columns", "time_unit", "gyro_unit", "accel_unit", "raw", "imu_topic",
                 "stamp"),
    Stream.POSES: ("columns", "time_unit", "quat_order", "position_unit", "mocap_topic",
                   "mocap_frame", "stamp", "rigid_body", "rotation", "mocap_rate",
                   "pose_source"),
}


@dataclass(frozen=True)
class ReadOptions:
    """The user's options for reading one session's files (None: not given).

    Attributes:
        imu_columns: The column map of the IMU file (``--columns`` or ``--imu-columns``).
        mocap_columns: The column map of the mocap file (``--columns`` or ``--mocap-columns``).
        columns_flags: The option each map came from, for messages (IMU, mocap).
        time_unit, gyro_unit, accel_unit, quat_order, position_unit: Units (None: the
            format's own).
        raw: The IMU readings are raw counts.
        recording: Topics (events), TF frame and stamp source of recordings.
        export: Options of mocap exports.
        pose_source: Which poses of a mav0 folder.
        crop: ``--start``/``--end`` (readers whose own checks depend on time respect it).
        imu_only: Read for a command without mocap (for the examples of messages).
    """

    imu_columns: ColumnMap | None = None
    mocap_columns: ColumnMap | None = None
    columns_flags: tuple[str, str] = ("--columns", "--columns")
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    quat_order: str | None = None
    position_unit: str | None = None
    raw: bool = False
    recording: RecordingOptions = field(default_factory=RecordingOptions)
    export: ExportOptions = field(default_factory=ExportOptions)
    pose_source: str = "auto"
    crop: Crop | None = None
    imu_only: bool = False

    def columns(self, stream: Stream) -> ColumnMap | None:
        return self.imu_columns if stream is Stream.IMU else self.mocap_columns

    def names_stream(self, stream: Stream) -> bool:
        """A map is given for ``stream``'s file: its own map, or ``--columns`` naming the
        stream's columns (a shared map naming only the other stream's is for the other file)."""
        cmap = self.columns(stream)
        if cmap is None:
            return False
        if self.columns_flag(stream) != "--columns":
            return True
        return cmap.has_imu if stream is Stream.IMU else cmap.has_mocap

    def columns_flag(self, stream: Stream) -> str:
        return self.columns_flags[0 if stream is Stream.IMU else 1]

    def units(self, *names: str) -> dict[str, str]:
        """The unit options among ``names`` that were given, by name."""
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}

    def value(self, name: str, stream: Stream) -> object:
        """The value of option ``name`` for ``stream``'s file (None or default: not given)."""
        if name == "columns":
            return self.columns(stream) if self.names_stream(stream) else None
        if name in ("imu_topic", "mocap_topic", "mocap_frame"):
            return getattr(self.recording, name)
        if name == "stamp":
            return None if self.recording.stamp == "header" else self.recording.stamp
        if name in ("rigid_body", "rotation", "mocap_rate"):
            return getattr(self.export, name)
        if name == "pose_source":
            return None if self.pose_source == "auto" else self.pose_source
        if name == "raw":
            return self.raw or None
        return getattr(self, name)

    def flag(self, name: str, stream: Stream) -> str:
        return self.columns_flag(stream) if name == "columns" else f"--{name.replace('_', '-')}"


ReadImu = Callable[[Path, ReadOptions, list[str]], ImuTable]
ReadPoses = Callable[[Path, ReadOptions, list[str]], PoseTable]
ReadBoth = Callable[[Path, ReadOptions, list[str]], tuple[ImuTable, PoseTable]]


@dataclass(frozen=True)
class Format:
    """One input format: the registry's record.

    Attributes:
        key: Short name (``crazyflie``).
        name: Human name for notes and messages (``Crazyflie uSD log``).
        sniff: True when a path holds this format, judged by its content (a folder's files).
        read_imu: Path, options, notes -> the IMU table; None if the format holds no IMU.
        read_poses: Path, options, notes -> the pose table; None if it holds no poses.
        read_both: Both streams in one pass over a file that holds both (None: the two
            readers one after the other).
        options: The options of :data:`STREAM_OPTIONS` the format uses; any other given for
            its file is refused (a column map, ``--raw``) or noted as ignored.
        own_units: What its units are, for the note on unit options it ignores.
        yields_to_columns: With a column map for its stream the file is read as a generic
            CSV instead (TUM: an 8-column table is also any table with a map).
    """

    key: str
    name: str
    sniff: Callable[[Path], bool]
    read_imu: ReadImu | None = None
    read_poses: ReadPoses | None = None
    read_both: ReadBoth | None = None
    options: frozenset[str] = frozenset()
    own_units: str = "SI units"
    yields_to_columns: bool = False

    def holds(self, stream: Stream) -> bool:
        return (self.read_imu if stream is Stream.IMU else self.read_poses) is not None


def screen(fmt: Format, path: Path, streams: tuple[Stream, ...], opts: ReadOptions,
           notes: list[str]) -> None:
    """Refuse a column map or ``--raw`` the format cannot use; note other options it ignores
    for this file (units in one note, then the rest)."""
    unused: list[tuple[str, Stream]] = []
    for stream in streams:
        for name in STREAM_OPTIONS[stream]:
            if name not in fmt.options and opts.value(name, stream) is not None \
                    and name not in (n for n, _ in unused):
                unused.append((name, stream))
    for name, stream in unused:
        if name == "columns":
            flag = opts.flag(name, stream)
            raise input_error(f"{flag} given, but this is a {fmt.name}, which has no columns "
                              "(its messages say what they hold)", f"drop {flag}", str(path))
        if name == "raw":
            raise input_error(f"--raw given for a {fmt.name}", f"its readings are in "
                              f"{fmt.own_units}: leave out --raw", str(path))
    units = [opts.flag(n, s) for n, s in unused if n in UNIT_OPTIONS]
    if units:
        notes.append(f"ignored {', '.join(units)} for {path}: it is a {fmt.name} "
                     f"({fmt.own_units})")
    rest = [opts.flag(n, s) for n, s in unused if n not in UNIT_OPTIONS]
    if rest:
        notes.append(f"ignored {', '.join(rest)} for {path}: a {fmt.name} does not use "
                     f"{'it' if len(rest) == 1 else 'them'}")
