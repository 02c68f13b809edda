"""One entry point for the CLI: find the formats of the input files and read both streams.

Formats are sniffed by :func:`sniff_format` (bags, mav0 folders, ULogs, Crazyflie uSD logs,
exports, EuRoC, TUM, generic CSVs with ``columns``).

A ``--columns`` map is used or refused, never dropped: it is parsed (and a malformed one
refused) before any file is read; an EuRoC CSV is read with it when it names that file's
stream (gyro/accel for the IMU, quat/pos for the poses; EuRoC's units stay the defaults), and a
recording or an export, which have no columns, refuse it.

The same file given as IMU and mocap (BROAD) is read once, with both streams. Unit options
left as None take the format's own units (EuRoC: ns, rad/s, m/s^2, m; TUM: s, m, xyzw;
generic: s, rad/s, m/s^2, wxyz, m); given ones override them for every file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import input_error
from mocap_calib.io.formats.bags import (
    RecordingOptions,
    bag_kind,
    open_bag,
    read_bag_imu,
    read_bag_mocap,
)
from mocap_calib.io.formats.columns import COLUMNS_FIX, ColumnMap, parse_columns
from mocap_calib.io.formats.crazyflie.usd import read_usd_imu, read_usd_poses
from mocap_calib.io.formats.crazyflie.usd_file import is_usd_log, read_usd_log
from mocap_calib.io.formats.euroc import (
    POSE_FOLDERS,
    find_mav0,
    header_kind,
    pose_folder,
    read_euroc_imu,
    read_euroc_poses,
    read_mav0,
)
from mocap_calib.io.formats.generic import read_generic
from mocap_calib.io.formats.hints import headerless_euroc_poses, unrecognised
from mocap_calib.io.formats.imu_tk import read_imu_tk_pair
from mocap_calib.io.formats.layout import WHITESPACE, sniff_layout
from mocap_calib.io.formats.mocap_exports import ExportOptions, read_export, sniff_export
from mocap_calib.io.formats.tum import read_tum
from mocap_calib.io.formats.ulog import read_ulog_imu, read_ulog_mocap
from mocap_calib.io.formats.ulog_file import is_ulog

#: Human-readable names of the formats :func:`sniff_format` returns.
FORMAT_NAMES = {"mav0": "EuRoC mav0 folder", "euroc_imu": "EuRoC IMU CSV",
                "euroc_poses": "EuRoC pose CSV", "tum": "TUM trajectory",
                "generic": "generic CSV", "rosbag1": "ROS 1 bag", "rosbag2": "ROS 2 bag",
                "mcap": "MCAP file", "ulog": "PX4 ULog", "motive": "Motive CSV export",
                "vicon-nexus": "Vicon Nexus CSV export",
                "vicon-tracker": "Vicon Tracker CSV export", "crazyflie": "Crazyflie uSD log"}
#: Formats holding time-stamped messages of several streams (read by topic).
RECORDINGS = ("rosbag1", "rosbag2", "mcap", "ulog", "crazyflie")
EXPORTS = ("motive", "vicon-nexus", "vicon-tracker")

def sniff_format(path: Path | str) -> str:
    """The format of an input path: a key of :data:`FORMAT_NAMES`.

    Raises:
        InputError: if the path does not exist or the file is empty.
    """
    path = Path(path)
    kind = bag_kind(path)
    if kind is not None:
        return kind
    if path.is_dir():
        return "mav0"
    if is_ulog(path):
        return "ulog"
    if path.is_file() and is_usd_log(path):
        return "crazyflie"
    export = sniff_export(path) if path.is_file() else None
    if export is not None:
        return export
    layout = sniff_layout(path)
    kind = header_kind(layout.names)
    if kind == "imu":
        return "euroc_imu"
    if kind == "poses":
        return "euroc_poses"
    if layout.sep == WHITESPACE and layout.n_fields == 8:
        return "tum"
    return "generic"


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.samefile(b)
    except OSError:
        return a.resolve() == b.resolve()


def _describe(kind: str, n: int, rate: float, duration: float, fmt: str, path: Path) -> str:
    noun = "samples" if kind == "IMU" else "poses"
    return (f"{kind}: {n} {noun} at {rate:.1f} Hz over {duration:.1f} s "
            f"({FORMAT_NAMES[fmt]} {path})")


def load_inputs(imu: Path | None, mocap: Path | None, mav0: Path | None, *,
                pose_source: str = "auto", columns: str | None = None,
                time_unit: str | None = None, gyro_unit: str | None = None,
                accel_unit: str | None = None, quat_order: str | None = None,
                position_unit: str | None = None, recording: RecordingOptions | None = None,
                export: ExportOptions | None = None,
                ) -> tuple[ImuSamples, MocapPoses, list[str]]:
    """Read the IMU and mocap streams from whatever the user passed.

    Args:
        imu: ``--imu`` file (or a mav0 folder), or None.
        mocap: ``--mocap`` file (or a mav0 folder), or None; may be the same file as ``imu``.
        mav0: ``--mav0`` folder (the mav0 folder or its parent), or None.
        pose_source: For mav0 folders: ``auto``, ``vicon0`` or ``groundtruth``.
        columns: ``--columns`` string for generic CSVs (see :mod:`mocap_calib.io.formats.generic`).
        time_unit: s, ms, us or ns; None for the format's own.
        gyro_unit: rad/s or deg/s; None for the format's own.
        accel_unit: m/s^2 or g; None for the format's own.
        quat_order: wxyz or xyzw; None for the format's own.
        position_unit: m, cm or mm; None for the format's own.
        recording: topics, TF child frame and stamp source for bags and ULogs.
        export: format, rigid body, rotation form and rate for Motive/Vicon exports.

    Returns:
        (IMU samples, mocap poses, one-line notes for the user).

    Raises:
        InputError: on missing or conflicting options and on any bad file.
    """
    units: dict[str, str] = {k: v for k, v in (
        ("time_unit", time_unit), ("gyro_unit", gyro_unit), ("accel_unit", accel_unit),
        ("quat_order", quat_order), ("position_unit", position_unit)) if v is not None}
    reader = _Reader(columns, pose_source, units, recording or RecordingOptions(),
                     export or ExportOptions())
    if mav0 is not None:
        if imu is not None or mocap is not None:
            raise input_error("--mav0 and --imu/--mocap both given",
                              "pass either --mav0 FOLDER or --imu FILE --mocap FILE")
        return reader.mav0(Path(mav0))
    if imu is None or mocap is None:
        missing = "--imu" if imu is None else "--mocap"
        raise input_error(f"no {missing} given",
                          "pass both --imu and --mocap (the same file if it holds both "
                          "streams), or --mav0 FOLDER")
    imu, mocap = Path(imu), Path(mocap)
    same = _same_file(imu, mocap) if imu.exists() and mocap.exists() else imu == mocap
    if same:
        return reader.combined(imu)
    samples = reader.imu(imu)
    poses = reader.mocap(mocap)
    return samples, poses, reader.notes


class _Reader:
    """Reads streams with the user's options, collecting notes."""

    def __init__(self, columns: str | None, pose_source: str, units: dict[str, str],
                 recording: RecordingOptions, export: ExportOptions) -> None:
        self.columns = columns
        self.colmap = None if columns is None else _column_map(columns)
        self.pose_source = pose_source
        self.units = units
        self.recording = recording
        self.export = export
        self.notes: list[str] = []

    def _ignore_options(self, path: Path, fmt: str) -> None:
        """Units do not apply to self-describing recordings; a column map is refused."""
        if self.columns is not None:
            raise _no_columns(path, fmt)
        given = [f"--{k.replace('_', '-')}" for k in self.units]
        if given:
            self.notes.append(f"ignored {', '.join(given)} for {path}: it is a "
                              f"{FORMAT_NAMES[fmt]} ({'its own' if fmt == 'crazyflie' else 'SI'} "
                              "units)")

    def _recording(self, path: Path, fmt: str, imu: bool, mocap: bool
                   ) -> tuple[ImuSamples | None, MocapPoses | None]:
        """Read the IMU and/or mocap streams of a bag or ULog (opened once)."""
        self._ignore_options(path, fmt)
        got_imu = got_mocap = None
        if fmt == "crazyflie":
            got_imu, got_mocap = _crazyflie(path, self.recording, imu, mocap, self.notes)
        elif fmt == "ulog":
            if imu:
                got_imu = read_ulog_imu(path, self.recording.imu_topic, self.notes)
            if mocap:
                got_mocap = read_ulog_mocap(path, self.recording.mocap_topic, self.notes)
        else:
            with open_bag(path) as bag:
                if imu:
                    got_imu = read_bag_imu(bag, self.recording, self.notes)
                if mocap:
                    got_mocap = read_bag_mocap(bag, self.recording, self.notes)
        if got_imu is not None:
            self._note_imu(got_imu, fmt, path)
        if got_mocap is not None:
            self._note_mocap(got_mocap, fmt, path)
        return got_imu, got_mocap

    def _export(self, path: Path, fmt: str) -> MocapPoses:
        self._ignore_options(path, fmt)
        return self._note_mocap(read_export(path, self.export, self.notes), fmt, path)

    def _kw(self, *names: str) -> dict[str, Any]:
        return {n: self.units[n] for n in names if n in self.units}

    def _note_imu(self, imu: ImuSamples, fmt: str, path: Path) -> ImuSamples:
        self.notes.append(_describe("IMU", len(imu), imu.rate_hz, imu.duration, fmt, path))
        return imu

    def _note_mocap(self, mocap: MocapPoses, fmt: str, path: Path) -> MocapPoses:
        self.notes.append(_describe("mocap", len(mocap), mocap.rate_hz, mocap.duration, fmt,
                                    path))
        if mocap.dropped_rows:
            self.notes.append(f"dropped {mocap.dropped_rows} mocap rows with NaN (occlusions)")
        return mocap

    def _euroc_imu(self, file: Path, fmt: str) -> ImuSamples:
        """An EuRoC IMU CSV, with the column map when it names the IMU's columns."""
        if self.colmap is None or not self.colmap.has_imu:
            imu = read_euroc_imu(file, **self._kw("time_unit", "gyro_unit", "accel_unit"))
            return self._note_imu(imu, fmt, file)
        imu, _ = read_generic(file, self.colmap, streams=["imu"], **{
            "time_unit": "ns", **self._kw("time_unit", "gyro_unit", "accel_unit")})
        assert imu is not None
        self.notes.append(f"read {file} with the --columns map")
        return self._note_imu(imu, fmt, file)

    def _euroc_poses(self, file: Path, fmt: str) -> MocapPoses:
        """An EuRoC pose CSV, with the column map when it names the poses' columns."""
        kw = self._kw("time_unit", "quat_order", "position_unit")
        if self.colmap is None or not self.colmap.has_mocap:
            return self._note_mocap(read_euroc_poses(file, **kw), fmt, file)
        _, mocap = read_generic(file, self.colmap, streams=["mocap"], **{"time_unit": "ns",
                                                                          **kw})
        assert mocap is not None
        self.notes.append(f"read {file} with the --columns map")
        return self._note_mocap(mocap, fmt, file)

    def _generic(self, path: Path, streams: list[str]
                 ) -> tuple[ImuSamples | None, MocapPoses | None]:
        if self.columns is None:
            raise unrecognised(path, streams[0] if len(streams) == 1 else "both")
        return read_generic(path, self.columns, streams=streams,
                            **self._kw("time_unit", "gyro_unit", "accel_unit", "quat_order",
                                       "position_unit"))

    def _pose_note(self, name: str, folder: Path) -> None:
        self.notes.append(f"poses from {folder}")
        if name == "groundtruth":
            self.notes.append("ground-truth poses are of the IMU (body) frame, not of the "
                              "marker body")

    def mav0(self, path: Path) -> tuple[ImuSamples, MocapPoses, list[str]]:
        if self.colmap is not None:  # each file read as the map says (or by its header)
            root = find_mav0(path)
            name, folder = pose_folder(root, self.pose_source)
            imu = self._euroc_imu(root / "imu0" / "data.csv", "mav0")
            self._pose_note(name, folder)
            return imu, self._euroc_poses(folder / "data.csv", "mav0"), self.notes
        m = read_mav0(path, self.pose_source, **self._kw(
            "time_unit", "gyro_unit", "accel_unit", "quat_order", "position_unit"))
        folder = m.root / POSE_FOLDERS[m.pose_source]
        self._note_imu(m.imu, "mav0", m.root / "imu0" / "data.csv")
        self._pose_note(m.pose_source, folder)
        self._note_mocap(m.mocap, "mav0", folder / "data.csv")
        return m.imu, m.mocap, self.notes

    def combined(self, path: Path) -> tuple[ImuSamples, MocapPoses, list[str]]:
        fmt = sniff_format(path)
        if fmt == "mav0":
            return self.mav0(path)
        if fmt in RECORDINGS:
            imu, mocap = self._recording(path, fmt, True, True)
            assert imu is not None and mocap is not None
            return imu, mocap, self.notes
        if fmt in EXPORTS:
            raise input_error(f"the same file is given as --imu and --mocap but it is a "
                              f"{FORMAT_NAMES[fmt]} (poses only)", "pass the IMU log with "
                              "--imu", str(path))
        if fmt == "euroc_imu" or fmt == "euroc_poses" or (fmt == "tum" and self.columns is None):
            held = "IMU samples" if fmt == "euroc_imu" else "poses"
            raise input_error(f"the same file is given as --imu and --mocap but it holds only "
                              f"{held} ({FORMAT_NAMES[fmt]})",
                              "pass the other stream's file too", str(path))
        imu, mocap = self._generic(path, ["imu", "mocap"])
        assert imu is not None and mocap is not None
        self._note_imu(imu, "generic", path)
        self._note_mocap(mocap, "generic", path)
        return imu, mocap, self.notes

    def imu(self, path: Path) -> ImuSamples:
        fmt = sniff_format(path)
        if fmt in RECORDINGS:
            imu, _ = self._recording(path, fmt, True, False)
            assert imu is not None
            return imu
        if fmt in EXPORTS:
            raise input_error(f"--imu is given a mocap export ({FORMAT_NAMES[fmt]})",
                              "pass it with --mocap and the IMU log with --imu", str(path))
        if fmt in ("mav0", "euroc_imu"):
            file = find_mav0(path) / "imu0" / "data.csv" if fmt == "mav0" else path
            return self._euroc_imu(file, fmt)
        if fmt == "euroc_poses" or (fmt == "tum" and self.columns is None):
            raise input_error(f"--imu is given a pose file ({FORMAT_NAMES[fmt]})",
                              "pass it with --mocap and the IMU file with --imu", str(path))
        imu, _ = self._generic(path, ["imu"])
        assert imu is not None
        return self._note_imu(imu, "generic", path)

    def mocap(self, path: Path) -> MocapPoses:
        if self.export.mocap_format is not None:
            return self._export(path, self.export.mocap_format)
        fmt = sniff_format(path)
        if fmt in RECORDINGS:
            _, mocap = self._recording(path, fmt, False, True)
            assert mocap is not None
            return mocap
        if fmt in EXPORTS:
            return self._export(path, fmt)
        kw = self._kw("time_unit", "quat_order", "position_unit")
        if fmt == "mav0":
            name, folder = pose_folder(find_mav0(path), self.pose_source)
            self._pose_note(name, folder)
            return self._euroc_poses(folder / "data.csv", fmt)
        if fmt == "euroc_poses":
            return self._euroc_poses(path, fmt)
        if fmt == "tum" and self.columns is None:
            if "time_unit" not in kw and (euroc := headerless_euroc_poses(path)) is not None:
                raise euroc
            return self._note_mocap(read_tum(path, **kw), fmt, path)
        if fmt == "euroc_imu":
            raise input_error("--mocap is given an IMU file (EuRoC IMU CSV)",
                              "pass it with --imu and the pose file with --mocap", str(path))
        _, mocap = self._generic(path, ["mocap"])
        assert mocap is not None
        return self._note_mocap(mocap, "generic", path)


def _crazyflie(path: Path, rec: RecordingOptions, imu: bool, mocap: bool, notes: list[str]
               ) -> tuple[ImuSamples | None, MocapPoses | None]:
    log = read_usd_log(path)
    table = read_usd_imu(log, rec.imu_topic, notes) if imu else None
    got = table.validate() if table is not None else None
    notes.extend(table.notes(got) if table is not None and got is not None else [])
    return got, read_usd_poses(log, rec.mocap_topic, notes).validate() if mocap else None


def _column_map(columns: str) -> ColumnMap:
    """The ``--columns`` map, refused now if malformed or if it names no stream."""
    colmap = parse_columns(columns)
    if not (colmap.has_imu or colmap.has_mocap):
        raise input_error("names neither IMU (gyro=, accel=) nor mocap (quat=, pos=) columns",
                          COLUMNS_FIX, "--columns")
    return colmap


def _no_columns(path: Path, fmt: str) -> Exception:
    return input_error(f"--columns given, but this is a {FORMAT_NAMES[fmt]}, which has no "
                       "columns (its messages say what they hold)", "drop --columns",
                       str(path))


def is_recording(path: Path | str) -> bool:
    """True for a ROS bag (1 or 2), a bare MCAP file or a PX4 ULog."""
    path = Path(path)
    return bag_kind(path) is not None or (not path.is_dir() and is_ulog(path)) or (
        path.is_file() and is_usd_log(path))


def _load_recording_imu(path: Path, topic: str | None, stamp: str
                        ) -> tuple[ImuSamples, list[str]]:
    """IMU samples of a bag or ULog without mocap."""
    fmt = sniff_format(path)
    if fmt not in RECORDINGS:
        raise input_error(f"not a bag or ULog ({FORMAT_NAMES.get(fmt, fmt)})",
                          "pass a .bag, a ROS 2 bag folder, a .mcap or a .ulg file", str(path))
    reader = _Reader(None, "auto", {}, RecordingOptions(imu_topic=topic, stamp=stamp),
                     ExportOptions())
    imu, _ = reader._recording(path, fmt, True, False)
    assert imu is not None
    return imu, reader.notes


def load_imu_file(path: Path | str | None, *, columns: str | None = None,
                  time_unit: str | None = None, gyro_unit: str | None = None,
                  accel_unit: str | None = None, raw: bool = False,
                  accel_file: Path | str | None = None, gyro_file: Path | str | None = None,
                  topic: str | None = None, stamp: str = "header"
                  ) -> tuple[ImuSamples, list[str]]:
    """Read an IMU log without mocap (:func:`load_inputs` needs both streams).

    Format as for :func:`load_inputs`, or imu_tk's two files (``accel_file``, ``gyro_file``).

    Args:
        path: ``--imu`` file or folder (None with ``accel_file`` and ``gyro_file``).
        columns: ``--columns`` string for generic CSVs.
        time_unit: s, ms, us or ns; None for the format's own (imu_tk's files: s).
        gyro_unit: rad/s or deg/s; None for the format's own.
        accel_unit: m/s^2 or g; None for the format's own.
        raw: the readings are raw sensor counts: read as they are, no unit check.
        accel_file: imu_tk's accelerometer file.
        gyro_file: imu_tk's gyroscope file.
        topic: bags and ULogs: the IMU topic (None: the only ``sensor_msgs/Imu`` topic, or
            ``sensor_combined``; ``sensor_gyro:N`` for one of several PX4 IMUs).
        stamp: bags: ``header`` or ``receive``.

    Returns:
        The samples and one-line notes for the user.

    Raises:
        InputError: no path, missing file, pose file given, unknown format, bad rows, no or
            ambiguous IMU topic.
    """
    if raw and (gyro_unit is not None or accel_unit is not None):
        raise input_error("--gyro-unit/--accel-unit given with --raw",
                          "raw counts have no unit: leave those options out")
    units: dict[str, str] = {k: v for k, v in (
        ("time_unit", time_unit), ("gyro_unit", gyro_unit), ("accel_unit", accel_unit))
        if v is not None}
    if accel_file is not None or gyro_file is not None:
        if columns is not None:
            raise input_error("--columns given with imu_tk's two files (--accel, --gyro), "
                              "whose layout is fixed", "drop --columns")
        return _load_imu_tk(path, accel_file, gyro_file, units, raw)
    if path is None:
        raise input_error("no --imu given", "pass the IMU log with --imu FILE (or imu_tk's two "
                          "files with --accel FILE --gyro FILE)")
    path = Path(path)
    colmap = None if columns is None else _column_map(columns)
    if is_recording(path):
        if colmap is not None:
            raise _no_columns(path, sniff_format(path))
        if raw:
            raise input_error("--raw given for a bag or ULog", "their IMU messages are in SI "
                              "units: leave out --raw", str(path))
        return _load_recording_imu(path, topic, stamp)
    fmt = sniff_format(path)
    notes: list[str] = []
    imu, file = _read_imu_csv(path, fmt, colmap, raw, units, notes)
    if raw:
        notes.append("readings taken as raw sensor counts")
    notes.append(_describe("IMU", len(imu), imu.rate_hz, imu.duration, fmt, file))
    return imu, notes


def _read_imu_csv(path: Path, fmt: str, colmap: ColumnMap | None, raw: bool,
                  units: dict[str, str], notes: list[str]) -> tuple[ImuSamples, Path]:
    """The IMU samples of an EuRoC or generic CSV (the column map used or refused)."""
    if fmt in ("mav0", "euroc_imu"):
        file = find_mav0(path) / "imu0" / "data.csv" if fmt == "mav0" else path
        if colmap is None:
            return read_euroc_imu(file, raw=raw, **units), file
        if not colmap.has_imu:
            raise input_error("names no IMU columns (gyro=, accel=) for the IMU log",
                              COLUMNS_FIX, "--columns")
        read, _ = read_generic(file, colmap, streams=["imu"], raw=raw,
                               **{"time_unit": "ns", **units})
        assert read is not None
        notes.append(f"read {file} with the --columns map")
        return read, file
    if fmt == "euroc_poses" or (fmt == "tum" and colmap is None):
        raise input_error(f"--imu is given a pose file ({FORMAT_NAMES[fmt]}), not an IMU log",
                          "pass the IMU file (EuRoC imu0/data.csv layout or a CSV with "
                          "--columns)", str(path))
    if colmap is None:
        raise unrecognised(path, "imu", "--columns 't=0,gyro=1:4,accel=4:7' (imu_tk's two "
                           "files: --accel FILE --gyro FILE)")
    read, _ = read_generic(path, colmap, streams=["imu"], raw=raw, **units)
    assert read is not None
    return read, path


def _load_imu_tk(path: Path | str | None, accel_file: Path | str | None,
                 gyro_file: Path | str | None, units: dict[str, str], raw: bool
                 ) -> tuple[ImuSamples, list[str]]:
    if path is not None:
        raise input_error("--imu and --accel/--gyro both given",
                          "pass either one IMU log (--imu) or imu_tk's two files "
                          "(--accel FILE --gyro FILE)")
    if accel_file is None or gyro_file is None:
        missing = "--accel" if accel_file is None else "--gyro"
        raise input_error(f"no {missing} given", "imu_tk's layout needs both files: "
                          "--accel FILE --gyro FILE")
    imu, notes = read_imu_tk_pair(accel_file, gyro_file, raw=raw,
                                  **{"time_unit": "s", **units})
    if raw:
        notes.append("readings taken as raw sensor counts")
    notes.append(f"IMU: {len(imu)} samples at {imu.rate_hz:.1f} Hz over {imu.duration:.1f} s "
                 f"(imu_tk files {accel_file}, {gyro_file})")
    return imu, notes
