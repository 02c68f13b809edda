"""One load path for every command: find each file's format in the registry, read its
streams, crop them to ``--start``/``--end``, then check them.

:func:`load_inputs` reads the IMU and the mocap streams (``calibrate``, ``diagnose``,
``groundtruth``, ``drift --mocap``); :func:`load_imu_file` the IMU alone (``allan``,
``multipos``, ``drift``). Both go through :func:`read_imu_table` / :func:`read_pose_table`:
the registry
(:mod:`mocap_calib.io.registry`) says which format a path holds and reads it into a table
(:mod:`mocap_calib.io.streams`); the options the format cannot use are refused or noted
(:func:`~mocap_calib.io.reading.screen`); the table is cropped, and only then checked
(:mod:`mocap_calib.io.validate`), so no refusal is about rows the user cropped away.

Column maps are parsed (and a malformed one refused) before any file is read: ``--columns``
covers both files, ``--imu-columns`` and ``--mocap-columns`` one each (they exclude
``--columns``). A map is used or refused, never dropped: an EuRoC CSV is read with it when it
names that file's stream, a recording or an export, which have no columns, refuses it.

The same file given as IMU and mocap (BROAD, a bag, a ULog, a Crazyflie log) is read once, with
both streams. Unit options left as None take the format's own units (EuRoC: ns, rad/s, m/s^2,
m; TUM: s, m, xyzw; generic: s, rad/s, m/s^2, wxyz, m); given ones override them for every file
that has units to give.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import input_error
from mocap_calib.io import registry
from mocap_calib.io.formats.columns import COLUMNS_FIX, ColumnMap, parse_columns
from mocap_calib.io.formats.imu_tk import imu_tk_pair_table
from mocap_calib.io.merge import merge_split_rows
from mocap_calib.io.reading import (
    ExportOptions,
    Format,
    ReadOptions,
    RecordingOptions,
    Stream,
    screen,
)
from mocap_calib.io.streams import (
    Crop,
    ImuTable,
    PoseTable,
    crop_imu_table,
    crop_pose_table,
)
from mocap_calib.io.validate import check_mocap_rate


def sniff_format(path: Path | str) -> str:
    """The key of the format the registry recognises in ``path``."""
    return registry.sniff(Path(path)).key


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.samefile(b)
    except OSError:
        return a.resolve() == b.resolve()


def _describe(kind: str, n: int, rate: float, duration: float, fmt: Format, path: str) -> str:
    noun = "samples" if kind == "IMU" else "poses"
    return (f"{kind}: {n} {noun} at {rate:.1f} Hz over {duration:.1f} s "
            f"({fmt.name} {path})")


@dataclass(frozen=True)
class ColumnMaps:
    """The column map of each file and the option each came from."""

    imu: ColumnMap | None = None
    mocap: ColumnMap | None = None
    flags: tuple[str, str] = ("--columns", "--columns")


def column_maps(columns: str | None, imu_columns: str | None = None,
                mocap_columns: str | None = None) -> ColumnMaps:
    """The per-file maps from the three options, refused here if malformed, if ``--columns``
    is combined with a per-file map, or if a per-file map names the other stream's columns."""
    if columns is not None and (imu_columns is not None or mocap_columns is not None):
        given = " and ".join(f for f, v in (("--imu-columns", imu_columns),
                                             ("--mocap-columns", mocap_columns)) if v)
        raise input_error(f"--columns and {given} both given", "give --columns (one map for "
                          "both files) or --imu-columns/--mocap-columns (one per file), not both")
    if columns is not None:
        cmap = _column_map(columns, "--columns")
        return ColumnMaps(cmap, cmap)
    imu_map = None if imu_columns is None else _column_map(imu_columns, "--imu-columns")
    mocap_map = None if mocap_columns is None else _column_map(mocap_columns, "--mocap-columns")
    if imu_map is not None and (imu_map.has_mocap or not imu_map.has_imu):
        raise input_error("the IMU file's map must name gyro= and accel= and no quat=/pos= "
                          "columns", "put the poses' columns in --mocap-columns", "--imu-columns")
    if mocap_map is not None and (mocap_map.has_imu or not mocap_map.has_mocap):
        raise input_error("the mocap file's map must name quat= and pos= and no gyro=/accel= "
                          "columns", "put the IMU's columns in --imu-columns", "--mocap-columns")
    return ColumnMaps(imu_map, mocap_map, ("--imu-columns", "--mocap-columns"))


def _column_map(columns: str, flag: str) -> ColumnMap:
    """A map, refused here if malformed or if it names no stream."""
    cmap = parse_columns(columns, flag)
    if not (cmap.has_imu or cmap.has_mocap):
        raise input_error("names neither IMU (gyro=, accel=) nor mocap (quat=, pos=) columns",
                          COLUMNS_FIX.replace("--columns", flag), flag)
    return cmap


@dataclass
class _Load:
    """One load: the options, the crop and the notes, and the IMU stamps the mocap is cropped
    against."""

    opts: ReadOptions
    notes: list[str] = field(default_factory=list)
    imu_span_ns: tuple[int, int] | None = None

    def imu(self, table: ImuTable, fmt: Format, path: Path) -> ImuSamples:
        table = merge_split_rows(table, self.notes)
        if len(table):
            self.imu_span_ns = (int(table.ns[0]), int(table.ns[-1]))
        imu = crop_imu_table(table, self.opts.crop).validate()
        self.notes.extend(table.notes(imu))
        if table.raw:
            self.notes.append("readings taken as raw sensor counts")
        self.notes.append(_describe("IMU", len(imu), imu.rate_hz, imu.duration, fmt,
                                    table.file or str(path)))
        return imu

    def poses(self, table: PoseTable, fmt: Format, path: Path) -> MocapPoses:
        if self.imu_span_ns is not None:
            table = crop_pose_table(table, self.opts.crop, *self.imu_span_ns)
        mocap = table.validate()
        self.notes.append(_describe("mocap", len(mocap), mocap.rate_hz, mocap.duration, fmt,
                                    table.file or str(path)))
        if mocap.dropped_rows:
            self.notes.append(f"dropped {mocap.dropped_rows} mocap rows with NaN (occlusions)")
        return mocap


def _refuse_stream(fmt: Format, stream: Stream, path: Path, imu_only: bool) -> Exception:
    if stream is Stream.IMU:
        fix = ("pass the IMU log with --imu (EuRoC imu0/data.csv layout, or a CSV with "
               "--columns)" if imu_only else "pass it with --mocap and the IMU log with --imu")
        return input_error(f"--imu is given a pose file ({fmt.name}), not an IMU log", fix,
                           str(path))
    return input_error(f"--mocap is given an IMU file ({fmt.name}), not poses",
                       "pass it with --imu and the pose file with --mocap", str(path))


def _format_for(path: Path, stream: Stream, opts: ReadOptions, notes: list[str],
                fmt: Format | None) -> Format:
    """The format of ``path`` (from the registry unless given), refused if it cannot hold
    ``stream``, with the options it cannot use screened."""
    fmt = fmt or registry.sniff(path, columns=opts.names_stream(stream))
    if not fmt.holds(stream):
        raise _refuse_stream(fmt, stream, path, opts.imu_only)
    screen(fmt, path, (stream,), opts, notes)
    return fmt


def read_imu_table(path: Path, opts: ReadOptions, notes: list[str],
                   fmt: Format | None = None) -> tuple[Format, ImuTable]:
    """The format and the IMU table of ``path``."""
    fmt = _format_for(path, Stream.IMU, opts, notes, fmt)
    assert fmt.read_imu is not None
    return fmt, fmt.read_imu(path, opts, notes)


def read_pose_table(path: Path, opts: ReadOptions, notes: list[str],
                    fmt: Format | None = None) -> tuple[Format, PoseTable]:
    """The format and the pose table of ``path``."""
    fmt = _format_for(path, Stream.POSES, opts, notes, fmt)
    assert fmt.read_poses is not None
    return fmt, fmt.read_poses(path, opts, notes)


def _combined(load: _Load, path: Path, fmt: Format | None
              ) -> tuple[ImuSamples, MocapPoses]:
    """Both streams of one file (read in one pass when its format can)."""
    opts = load.opts
    fmt = fmt or registry.sniff(path, columns=opts.names_stream(Stream.IMU)
                                or opts.names_stream(Stream.POSES))
    if not (fmt.holds(Stream.IMU) and fmt.holds(Stream.POSES)):
        held = "IMU samples" if fmt.holds(Stream.IMU) else "poses"
        raise input_error(f"the same file is given as --imu and --mocap but it holds only "
                          f"{held} ({fmt.name})", "pass the other stream's file too", str(path))
    screen(fmt, path, (Stream.IMU, Stream.POSES), opts, load.notes)
    assert fmt.read_imu is not None and fmt.read_poses is not None
    if fmt.read_both is None:  # each stream checked before the next is read
        imu = load.imu(fmt.read_imu(path, opts, load.notes), fmt, path)
        return imu, load.poses(fmt.read_poses(path, opts, load.notes), fmt, path)
    imu_t, pose_t = fmt.read_both(path, opts, load.notes)
    imu = load.imu(imu_t, fmt, path)
    return imu, load.poses(pose_t, fmt, path)


def load_inputs(imu: Path | None, mocap: Path | None, mav0: Path | None, *,
                pose_source: str = "auto", columns: str | None = None,
                imu_columns: str | None = None, mocap_columns: str | None = None,
                time_unit: str | None = None, gyro_unit: str | None = None,
                accel_unit: str | None = None, quat_order: str | None = None,
                position_unit: str | None = None, recording: RecordingOptions | None = None,
                export: ExportOptions | None = None, crop: Crop | None = None,
                min_mocap_rate_hz: float | None = None,
                ) -> tuple[ImuSamples, MocapPoses, list[str]]:
    """Read the IMU and mocap streams from whatever the user passed.

    Args:
        imu: ``--imu`` file (or a mav0 folder), or None.
        mocap: ``--mocap`` file (or a mav0 folder), or None; may be the same file as ``imu``.
        mav0: ``--mav0`` folder (the mav0 folder or its parent), or None.
        pose_source: For mav0 folders: ``auto``, ``vicon0`` or ``groundtruth``.
        columns: ``--columns`` map for both files (see :mod:`mocap_calib.io.formats.generic`).
        imu_columns: ``--imu-columns`` map of the IMU file alone.
        mocap_columns: ``--mocap-columns`` map of the mocap file alone.
        time_unit: s, ms, us or ns; None for the format's own.
        gyro_unit: rad/s or deg/s; None for the format's own.
        accel_unit: m/s^2 or g; None for the format's own.
        quat_order: wxyz or xyzw; None for the format's own.
        position_unit: m, cm or mm; None for the format's own.
        recording: topics (events), TF child frame and stamp source for recordings.
        export: format, rigid body, rotation form and rate for Motive/Vicon exports.
        crop: ``--start``/``--end``, applied before the checks.
        min_mocap_rate_hz: Refuse mocap slower than this (None: no limit).

    Returns:
        (IMU samples, mocap poses, one-line notes for the user).

    Raises:
        InputError: on missing or conflicting options and on any bad file.
    """
    maps = column_maps(columns, imu_columns, mocap_columns)
    opts = ReadOptions(maps.imu, maps.mocap, maps.flags, time_unit=time_unit,
                       gyro_unit=gyro_unit, accel_unit=accel_unit, quat_order=quat_order,
                       position_unit=position_unit, recording=recording or RecordingOptions(),
                       export=export or ExportOptions(), pose_source=pose_source, crop=crop)
    load = _Load(opts)
    if mav0 is not None:
        if imu is not None or mocap is not None:
            raise input_error("--mav0 and --imu/--mocap both given",
                              "pass either --mav0 FOLDER or --imu FILE --mocap FILE")
        got_imu, got_mocap = _combined(load, Path(mav0), registry.find("mav0"))
    elif imu is None or mocap is None:
        missing = "--imu" if imu is None else "--mocap"
        raise input_error(f"no {missing} given",
                          "pass both --imu and --mocap (the same file if it holds both "
                          "streams), or --mav0 FOLDER")
    else:
        imu, mocap = Path(imu), Path(mocap)
        same = _same_file(imu, mocap) if imu.exists() and mocap.exists() else imu == mocap
        forced = (registry.find(opts.export.mocap_format)
                  if opts.export.mocap_format is not None else None)
        if same and forced is None:
            got_imu, got_mocap = _combined(load, imu, None)
        else:
            fmt, imu_t = read_imu_table(imu, opts, load.notes)
            got_imu = load.imu(imu_t, fmt, imu)
            fmt, pose_t = read_pose_table(mocap, opts, load.notes, forced)
            got_mocap = load.poses(pose_t, fmt, mocap)
    if min_mocap_rate_hz is not None:
        check_mocap_rate(got_mocap, min_mocap_rate_hz)
    return got_imu, got_mocap, load.notes


def load_imu_file(path: Path | str | None, *, columns: str | None = None,
                  time_unit: str | None = None, gyro_unit: str | None = None,
                  accel_unit: str | None = None, raw: bool = False,
                  accel_file: Path | str | None = None, gyro_file: Path | str | None = None,
                  topic: str | None = None, stamp: str = "header", crop: Crop | None = None
                  ) -> tuple[ImuSamples, list[str]]:
    """Read an IMU log without mocap (:func:`load_inputs` needs both streams).

    Format as for :func:`load_inputs`, or imu_tk's two files (``accel_file``, ``gyro_file``;
    :mod:`mocap_calib.io.formats.imu_tk`).

    Args:
        path: ``--imu`` file or folder (None with ``accel_file`` and ``gyro_file``).
        columns: ``--columns`` string for generic CSVs.
        time_unit: s, ms, us or ns; None for the format's own (imu_tk's files: s).
        gyro_unit: rad/s or deg/s; None for the format's own.
        accel_unit: m/s^2 or g; None for the format's own.
        raw: the readings are raw sensor counts: read as they are, no unit check.
        accel_file: imu_tk's accelerometer file.
        gyro_file: imu_tk's gyroscope file.
        topic: recordings: the IMU topic (None: the only ``sensor_msgs/Imu`` topic, or
            ``sensor_combined``; ``sensor_gyro:N`` for one of several PX4 IMUs; Crazyflie:
            ``GYRO_EVENT,ACCEL_EVENT``).
        stamp: bags: ``header`` or ``receive``.
        crop: ``--start``/``--end``, applied before the checks.

    Returns:
        The samples and one-line notes for the user.

    Raises:
        InputError: no path, missing file, pose file given, unknown format, bad rows, no or
            ambiguous IMU topic.
    """
    if raw and (gyro_unit is not None or accel_unit is not None):
        raise input_error("--gyro-unit/--accel-unit given with --raw",
                          "raw counts have no unit: leave those options out")
    cmap = None if columns is None else _column_map(columns, "--columns")
    opts = ReadOptions(imu_columns=cmap, time_unit=time_unit, gyro_unit=gyro_unit,
                       accel_unit=accel_unit, raw=raw,
                       recording=RecordingOptions(imu_topic=topic, stamp=stamp), crop=crop,
                       imu_only=True)
    load = _Load(opts)
    if accel_file is not None or gyro_file is not None:
        return load.imu(_imu_tk(path, accel_file, gyro_file, opts, load.notes), IMU_TK,
                        Path(str(accel_file))), load.notes
    if path is None:
        raise input_error("no --imu given", "pass the IMU log with --imu FILE (or imu_tk's two "
                          "files with --accel FILE --gyro FILE)")
    if cmap is not None and not cmap.has_imu:
        raise input_error("names no IMU columns (gyro=, accel=) for the IMU log",
                          COLUMNS_FIX, "--columns")
    path = Path(path)
    fmt, table = read_imu_table(path, opts, load.notes)
    return load.imu(table, fmt, path), load.notes


#: imu_tk's pair of files, for the notes (no single path to recognise: not in the registry).
IMU_TK = Format("imu_tk", "imu_tk files", lambda p: False)


def _imu_tk(path: Path | str | None, accel_file: Path | str | None,
            gyro_file: Path | str | None, opts: ReadOptions, notes: list[str]) -> ImuTable:
    if opts.imu_columns is not None:
        raise input_error("--columns given with imu_tk's two files (--accel, --gyro), "
                          "whose layout is fixed", "drop --columns")
    if path is not None:
        raise input_error("--imu and --accel/--gyro both given",
                          "pass either one IMU log (--imu) or imu_tk's two files "
                          "(--accel FILE --gyro FILE)")
    if accel_file is None or gyro_file is None:
        missing = "--accel" if accel_file is None else "--gyro"
        raise input_error(f"no {missing} given", "imu_tk's layout needs both files: "
                          "--accel FILE --gyro FILE")
    return imu_tk_pair_table(accel_file, gyro_file, notes, raw=opts.raw,
                             **{"time_unit": "s", **opts.units("time_unit", "gyro_unit",
                                                                "accel_unit")})
