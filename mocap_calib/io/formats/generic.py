"""Generic CSV reader: any delimited text file, with a column map and units.

One file may hold an IMU stream (time, gyro xyz, accel xyz), a mocap stream (time, quaternion,
position xyz) or both (as BROAD does). Values are converted to the project's units on reading:
integer nanosecond stamps, rad/s, m/s^2, metres, quaternions ``[w, x, y, z]``. Mocap rows with
NaN are occlusions: they are dropped and counted in ``MocapPoses.dropped_rows``; the IMU stream
keeps every row.

Layout sniffing: the delimiter is taken from the first data row (``;`` if present, else ``,``,
else whitespace); the first data row is the first line that is not blank, not a ``#`` comment
and mostly numeric; the non-blank line just before it, with a leading ``#`` removed, is the
header (its names can be used in the column map). Later ``#`` lines are comments. A
``;``-separated file whose numbers use a decimal comma (``0,5;1,25``) is read as such.
Time columns are parsed from their text, so decimal seconds become exact integer nanoseconds.

Column-map string (``--columns``), parsed by :func:`parse_columns`::

    t=0,gyro=1:4,accel=4:7,quat=10:14,pos=14:17
    t=t [s],gyro=gyr_x|gyr_y|gyr_z,accel=acc_x|acc_y|acc_z
    broad

- comma-separated ``key=columns`` items; keys: ``t`` (or ``time``), ``gyro`` (``gyr``, ``w``),
  ``accel`` (``acc``, ``a``), ``quat`` (``q``), ``pos`` (``position``, ``p``); each key once;
- ``columns`` is a 0-based half-open range ``A:B`` (as a Python slice), or ``|``-separated
  columns, each a 0-based index or a header name; a name matches the header exactly, or
  without its bracketed unit and case-insensitively (``gyr_x`` matches ``gyr_x [rad/s]``);
- counts: ``t`` 1 column, ``gyro``/``accel``/``pos`` 3, ``quat`` 4 in the order given by
  ``--quat-order`` (``wxyz`` or ``xyzw``);
- the IMU stream needs ``gyro`` and ``accel``, the mocap stream ``quat`` and ``pos``; a group
  may be absent when its stream is not in the file;
- a preset name alone (``broad``) selects a preset (:data:`PRESETS`);
- header names cannot contain ``,``, ``|`` or ``=``; use indices for those columns.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.policy import ACCEL_UNITS, GYRO_UNITS, POSITION_UNITS
from mocap_calib.errors import input_error
from mocap_calib.io.formats.columns import (
    COLUMNS_FIX,
    Col,
    ColumnMap,
    parse_columns,
)
from mocap_calib.io.formats.hints import COLUMNS_EXAMPLE, IMU_ONLY_EXAMPLE, unrecognised
from mocap_calib.io.formats.layout import (
    Layout,
    name_key,
    numeric_column,
    read_table,
    sniff_layout,
)
from mocap_calib.io.formats.stamps import parse_stamps
from mocap_calib.io.reading import UNIT_OPTIONS, Format, ReadOptions, Stream
from mocap_calib.io.streams import ImuTable, PoseTable
from mocap_calib.io.validate import QUAT_ORDERS, TIME_UNITS, check_unit

Array = NDArray[np.float64]



def read_indexed(layout: Layout, **kw: Any) -> tuple[ImuSamples | None, MocapPoses | None]:
    """The checked streams of :func:`indexed_tables` (same arguments)."""
    imu, poses = indexed_tables(layout, **kw)
    return (None if imu is None else imu.validate(),
            None if poses is None else poses.validate())


def indexed_tables(layout: Layout, *, time: int, gyro: Sequence[int] | None = None,
                   accel: Sequence[int] | None = None, quat: Sequence[int] | None = None,
                   position: Sequence[int] | None = None, time_unit: str = "s",
                   gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", quat_order: str = "wxyz",
                   position_unit: str = "m", raw: bool = False
                   ) -> tuple[ImuTable | None, PoseTable | None]:
    """Read the streams whose (resolved, 0-based) columns are given and convert them.

    The building block of every text reader: EuRoC and TUM call it with their fixed columns.

    Args:
        layout: The file's layout (:func:`sniff_layout`).
        time: Time column.
        gyro: Gyro x, y, z columns (IMU stream, with ``accel``).
        accel: Accel x, y, z columns.
        quat: Quaternion columns in ``quat_order`` (mocap stream, with ``position``).
        position: Position x, y, z columns.
        time_unit: s, ms, us or ns.
        gyro_unit: rad/s or deg/s.
        accel_unit: m/s^2 or g.
        quat_order: wxyz or xyzw.
        position_unit: m, cm or mm.
        raw: the IMU readings are raw counts: no unit conversion or check.

    Returns:
        (IMU table or None, pose table or None), not yet checked.
    """
    check_unit(time_unit, TIME_UNITS, "--time-unit")
    check_unit(gyro_unit, GYRO_UNITS, "--gyro-unit")
    check_unit(accel_unit, ACCEL_UNITS, "--accel-unit")
    check_unit(quat_order, QUAT_ORDERS, "--quat-order")
    check_unit(position_unit, POSITION_UNITS, "--position-unit")
    indices = [time]
    for group in (gyro, accel, quat, position):
        indices += list(group or ())
    table = read_table(layout, indices, time)
    lines = layout.lines()
    ns = parse_stamps(table.text[time], time_unit, layout.label(time), lines, layout.decimal)

    def block(cols: Sequence[int]) -> Array:
        return np.stack([numeric_column(table, c, layout, lines) for c in cols], axis=1)

    imu = mocap = None
    if gyro is not None and accel is not None:
        g = block(gyro) * GYRO_UNITS[gyro_unit]
        a = block(accel) * ACCEL_UNITS[accel_unit]
        imu = ImuTable(ns, g, a, lines, time_unit=time_unit, gyro_unit=gyro_unit,
                       accel_unit=accel_unit, raw=raw)
    if quat is not None and position is not None:
        q = block(quat)
        if quat_order == "xyzw":
            q = q[:, [3, 0, 1, 2]]
        p = block(position) * POSITION_UNITS[position_unit]
        mocap = PoseTable(ns, np.ascontiguousarray(q), p, lines, time_unit=time_unit,
                          position_unit=position_unit)
    return imu, mocap


def resolve_column(col: Col, layout: Layout, flag: str = "--columns") -> int:
    """0-based index of a column given by index or header name.

    Raises:
        InputError: if the index is out of range or the name is not in the header.
    """
    if isinstance(col, int):
        if not 0 <= col < layout.n_fields:
            raise input_error(f"column {col} does not exist (the first data row has "
                              f"{layout.n_fields} columns)", COLUMNS_FIX.replace("--columns", flag),
                              layout.source,
                              layout.skip + 1)
        return col
    if layout.names is None:
        raise input_error(f"{flag} names column {col!r} but the file has no header line",
                          f"use 0-based column numbers in {flag}", layout.source)
    names = layout.names[: layout.n_fields]
    if col in names:
        return names.index(col)
    hits = [i for i, n in enumerate(names) if name_key(n) == name_key(col)]
    if len(hits) == 1:
        return hits[0]
    shown = ", ".join(names)
    raise input_error(f"no {'unique ' if hits else ''}column named {col!r} in the header "
                      f"({shown})", f"use a header name or a 0-based index in {flag}",
                      layout.source, layout.header_line)


def read_generic(path: Path | str, columns: ColumnMap | str, **kw: Any
                 ) -> tuple[ImuSamples | None, MocapPoses | None]:
    """The checked streams of :func:`generic_tables` (same arguments)."""
    imu, poses = generic_tables(path, columns, **kw)
    return (None if imu is None else imu.validate(),
            None if poses is None else poses.validate())


def generic_tables(path: Path | str, columns: ColumnMap | str, *, time_unit: str = "s",
                   gyro_unit: str = "rad/s", accel_unit: str = "m/s^2",
                   quat_order: str = "wxyz", position_unit: str = "m",
                   streams: Collection[str] | None = None, raw: bool = False,
                   flag: str = "--columns") -> tuple[ImuTable | None, PoseTable | None]:
    """Read an IMU and/or a mocap stream from a delimited text file with a column map.

    Args:
        path: The file.
        columns: A :class:`ColumnMap` or a ``--columns`` string (see the module doc).
        time_unit: Unit of the time column: s, ms, us or ns.
        gyro_unit: rad/s or deg/s.
        accel_unit: m/s^2 or g.
        quat_order: Order of the 4 quaternion columns: wxyz or xyzw.
        position_unit: m, cm or mm.
        streams: Streams to read (``"imu"``, ``"mocap"``); each must be in the column map.
            None reads whatever the column map describes.
        raw: the IMU readings are raw counts (no unit conversion or check).
        flag: The option the map came from, for messages.

    Returns:
        (IMU table or None, pose table or None), in SI units with ``[w, x, y, z]``.

    Raises:
        InputError: on any problem with the options or the file (one line, with the fix).
    """
    colmap = parse_columns(columns) if isinstance(columns, str) else columns.check()
    if streams is None:
        streams = [s for s, ok in (("imu", colmap.has_imu), ("mocap", colmap.has_mocap)) if ok]
    if "imu" in streams and not colmap.has_imu:
        raise input_error("no IMU columns (gyro= and accel=) for the IMU file", COLUMNS_FIX,
                          flag)
    if "mocap" in streams and not colmap.has_mocap:
        raise input_error("no mocap columns (quat= and pos=) for the mocap file", COLUMNS_FIX,
                          flag)
    if not streams:
        raise input_error("names neither IMU (gyro=, accel=) nor mocap (quat=, pos=) columns",
                          COLUMNS_FIX, flag)
    layout = sniff_layout(path)

    def res(cols: tuple[Col, ...] | None, want: bool) -> list[int] | None:
        return ([resolve_column(c, layout, flag) for c in cols] if want and cols is not None
                else None)

    groups = {"t": [resolve_column(colmap.time, layout, flag)],
              "gyro": res(colmap.gyro, "imu" in streams),
              "accel": res(colmap.accel, "imu" in streams),
              "quat": res(colmap.quat, "mocap" in streams),
              "pos": res(colmap.position, "mocap" in streams)}
    _check_distinct(groups, layout, flag)
    return indexed_tables(
        layout, time=groups["t"][0], gyro=groups["gyro"], accel=groups["accel"],
        quat=groups["quat"], position=groups["pos"],
        time_unit=time_unit, gyro_unit=gyro_unit, accel_unit=accel_unit, quat_order=quat_order,
        position_unit=position_unit, raw=raw)


def _check_distinct(groups: dict[str, list[int] | None], layout: Layout,
                    flag: str = "--columns") -> None:
    """Raise when the column map reads one column twice (``gyro=1:4,accel=1:4``): the
    calibration would then fit one signal against itself."""
    seen: dict[int, str] = {}
    for key, cols in groups.items():
        for c in cols or ():
            if c in seen:
                where = f"{seen[c]}= and {key}=" if seen[c] != key else f"{key}= twice"
                raise input_error(f"column {layout.label(c)} is used twice ({where})",
                                  COLUMNS_FIX, flag)
            seen[c] = key


# --- the registry's record: any delimited table, with a column map -----------------------------

def _imu(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    cmap = opts.imu_columns
    if cmap is None:
        raise unrecognised(path, "imu", IMU_ONLY_EXAMPLE if opts.imu_only else COLUMNS_EXAMPLE)
    imu, _ = generic_tables(path, cmap, streams=["imu"], raw=opts.raw,
                            flag=opts.columns_flag(Stream.IMU),
                            **opts.units("time_unit", "gyro_unit", "accel_unit"))
    assert imu is not None
    return imu


def _poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    cmap = opts.mocap_columns
    if cmap is None:
        raise unrecognised(path, "mocap")
    _, poses = generic_tables(path, cmap, streams=["mocap"], flag=opts.columns_flag(Stream.POSES),
                              **opts.units("time_unit", "quat_order", "position_unit"))
    assert poses is not None
    return poses


def _both(path: Path, opts: ReadOptions, notes: list[str]) -> tuple[ImuTable, PoseTable]:
    if opts.imu_columns is None and opts.mocap_columns is None:
        raise unrecognised(path, "both")
    if opts.imu_columns is not opts.mocap_columns:  # one map per stream: read each
        return _imu(path, opts, notes), _poses(path, opts, notes)
    imu, poses = generic_tables(path, opts.imu_columns, streams=["imu", "mocap"],
                                raw=opts.raw, flag=opts.columns_flag(Stream.IMU),
                                **opts.units(*UNIT_OPTIONS))
    assert imu is not None and poses is not None
    return imu, poses


FORMAT = Format("generic", "generic CSV", lambda p: True, _imu, _poses, _both,
                frozenset({"columns", *UNIT_OPTIONS, "raw"}))
