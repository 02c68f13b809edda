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

import re
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import input_error
from mocap_calib.io.checks import (
    ACCEL_UNITS,
    GYRO_UNITS,
    POSITION_UNITS,
    QUAT_ORDERS,
    TIME_UNITS,
    Lines,
    check_unit,
    validate_imu,
    validate_mocap,
)

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
Col = int | str

#: Standard gravity, the definition of the unit g (not the local gravity of the session).
G0 = 9.80665
#: pandas separator for whitespace-delimited files.
WHITESPACE = r"\s+"
_HEAD_LINES = 200
_INT64_MAX = np.iinfo(np.int64).max


@dataclass(frozen=True)
class ColumnMap:
    """Which columns of a generic CSV hold which quantity (0-based indices or header names).

    Attributes:
        time: The time column.
        gyro: Gyro x, y, z, or None.
        accel: Accel x, y, z, or None.
        quat: Quaternion, 4 columns in the file's order (see ``quat_order``), or None.
        position: Position x, y, z, or None.
    """

    time: Col = 0
    gyro: tuple[Col, ...] | None = None
    accel: tuple[Col, ...] | None = None
    quat: tuple[Col, ...] | None = None
    position: tuple[Col, ...] | None = None

    @property
    def has_imu(self) -> bool:
        return self.gyro is not None and self.accel is not None

    @property
    def has_mocap(self) -> bool:
        return self.quat is not None and self.position is not None

    def check(self) -> ColumnMap:
        """Raise if a group has the wrong number of columns or a stream is half given."""
        for key, cols, n in (("gyro", self.gyro, 3), ("accel", self.accel, 3),
                             ("quat", self.quat, 4), ("pos", self.position, 3)):
            if cols is not None and len(cols) != n:
                raise input_error(f"{key}= names {len(cols)} columns, not {n}",
                                  _COLUMNS_FIX, "--columns")
        if (self.gyro is None) != (self.accel is None):
            raise input_error("the IMU stream needs both gyro= and accel=", _COLUMNS_FIX,
                              "--columns")
        if (self.quat is None) != (self.position is None):
            raise input_error("the mocap stream needs both quat= and pos=", _COLUMNS_FIX,
                              "--columns")
        return self


_COLUMNS_FIX = ("write --columns like 't=0,gyro=1:4,accel=4:7,quat=7:11,pos=11:14' "
                "(0-based, A:B is a range, names separated by |)")

#: BROAD (``../shared/data/broad_*/data.csv``): seconds, rad/s, m/s^2, wxyz, metres.
BROAD = ColumnMap(
    time="t [s]",
    gyro=("gyr_x [rad/s]", "gyr_y [rad/s]", "gyr_z [rad/s]"),
    accel=("acc_x [m/s^2]", "acc_y [m/s^2]", "acc_z [m/s^2]"),
    quat=("opt_qw", "opt_qx", "opt_qy", "opt_qz"),
    position=("opt_px [m]", "opt_py [m]", "opt_pz [m]"),
)

PRESETS: dict[str, ColumnMap] = {"broad": BROAD}

_KEYS = {"t": "time", "time": "time", "gyro": "gyro", "gyr": "gyro", "w": "gyro",
         "accel": "accel", "acc": "accel", "a": "accel", "quat": "quat", "q": "quat",
         "pos": "position", "position": "position", "p": "position"}


def parse_columns(spec: str) -> ColumnMap:
    """Build a :class:`ColumnMap` from a ``--columns`` string (grammar in the module doc).

    Args:
        spec: E.g. ``"t=0,gyro=1:4,accel=4:7"`` or ``"broad"``.

    Returns:
        The column map.

    Raises:
        InputError: on a malformed string.
    """
    text = spec.strip()
    if text.lower() in PRESETS:
        return PRESETS[text.lower()]
    found: dict[str, tuple[Col, ...]] = {}
    for item in (i.strip() for i in text.split(",")):
        if not item:
            continue
        key, eq, value = item.partition("=")
        field = _KEYS.get(key.strip().lower())
        if not eq or field is None:
            raise input_error(f"cannot read {item!r} (keys: t, gyro, accel, quat, pos)",
                              _COLUMNS_FIX, "--columns")
        if field in found:
            raise input_error(f"{key.strip()}= is given twice", _COLUMNS_FIX, "--columns")
        found[field] = _parse_cols(value.strip())
    if "time" not in found:
        raise input_error("no time column (t=)", _COLUMNS_FIX, "--columns")
    if len(found["time"]) != 1:
        raise input_error(f"t= names {len(found['time'])} columns, not 1", _COLUMNS_FIX,
                          "--columns")
    return ColumnMap(time=found["time"][0], gyro=found.get("gyro"), accel=found.get("accel"),
                     quat=found.get("quat"), position=found.get("position")).check()


def _parse_cols(value: str) -> tuple[Col, ...]:
    m = re.fullmatch(r"(\d+)\s*:\s*(\d+)", value)
    if m:
        cols: tuple[Col, ...] = tuple(range(int(m.group(1)), int(m.group(2))))
    else:
        cols = tuple(int(v) if re.fullmatch(r"\d+", v) else v
                     for v in (p.strip() for p in value.split("|")))
    if not cols or any(c == "" for c in cols):
        raise input_error(f"empty column in {value!r}", _COLUMNS_FIX, "--columns")
    return cols


# --- layout sniffing and table reading (shared with the EuRoC and TUM readers) ---------------

@dataclass(frozen=True)
class Layout:
    """How a delimited text file is laid out (found from its first lines).

    Attributes:
        path: The file.
        sep: pandas separator: ``","``, ``";"`` or :data:`WHITESPACE`.
        skip: Raw lines before the first data row.
        names: Header names (leading ``#`` and spaces stripped), or None without a header.
        header_line: 1-based line of the header, or None.
        n_fields: Fields in the first data row.
        decimal: Decimal mark: ``"."``, or ``","`` in ``;``-separated files that use it.
    """

    path: Path
    sep: str
    skip: int
    names: tuple[str, ...] | None
    header_line: int | None
    n_fields: int
    decimal: str = "."

    @property
    def source(self) -> str:
        return str(self.path)

    def lines(self) -> Lines:
        """Row-to-line map for messages about this file."""
        return Lines(self.source, self.path, self.skip, "#")

    def label(self, index: int) -> str:
        """Column name for messages: the header name if there is one."""
        if self.names is not None and index < len(self.names):
            return f"'{self.names[index]}'"
        return f"{index} (0-based)"


def name_key(name: str) -> str:
    """Header name without ``#``, bracketed unit and case: ``'#timestamp [ns]' -> 'timestamp'``."""
    n = name.strip().lstrip("#").strip()
    return re.sub(r"\s*\[[^\]]*\]$", "", n).strip().lower()


def _detect_sep(line: str) -> str:
    if ";" in line:
        return ";"
    if "," in line:
        return ","
    return WHITESPACE


def _split(line: str, sep: str) -> list[str]:
    if sep == WHITESPACE:
        return line.split()
    return [t.strip() for t in line.split(sep)]


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _mostly_numeric(tokens: list[str]) -> bool:
    return sum(_is_number(t) for t in tokens) * 2 > len(tokens)


def sniff_layout(path: Path | str) -> Layout:
    """Find the delimiter, header and first data row of a delimited text file.

    Args:
        path: The file.

    Returns:
        Its layout.

    Raises:
        InputError: if the file is missing, empty, or has no numeric data row near its start.
    """
    path = Path(path)
    source = str(path)
    if path.is_dir():
        raise input_error("is a folder, not a file", "pass the CSV file inside it (or --mav0 "
                          "for an EuRoC mav0 folder)", source)
    if not path.is_file():
        raise input_error("file not found", "check the path", source)
    head: list[str] = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for _ in range(_HEAD_LINES):
            text = f.readline()
            if not text:
                break
            head.append(text)
    prev: tuple[int, str] | None = None
    for idx, text in enumerate(head):
        s = text.strip().lstrip("\ufeff")
        if not s:
            continue
        if not s.startswith("#"):
            sep = _detect_sep(s)
            tokens = _split(s, sep)
            decimal = "."
            commas = [t for t in tokens if "," in t]
            if sep == ";" and commas and all(_is_number(t.replace(",", ".")) for t in commas):
                decimal = ","  # European spreadsheet export: "0,5;1,25"
                tokens = [t.replace(",", ".") for t in tokens]
            if _mostly_numeric(tokens):
                names = None
                header_line = None
                if prev is not None:
                    header_line = prev[0] + 1
                    names = tuple(t.strip() for t in _split(prev[1].lstrip("#").strip(), sep))
                    if names:
                        names = (names[0].lstrip("#").strip(),) + names[1:]
                return Layout(path, sep, idx, names, header_line, len(tokens), decimal)
        prev = (idx, s)
    if prev is None:
        raise input_error("the file is empty", "pass the file that holds the recording", source)
    if len(head) < _HEAD_LINES:
        raise input_error("the file has a header but no data rows",
                          "pass the file that holds the recording", source)
    raise input_error(f"no numeric data row in the first {_HEAD_LINES} lines",
                      "check that this is a delimited text file of numbers", source)


def read_frame(layout: Layout, indices: Collection[int], time_index: int) -> pd.DataFrame:
    """Read the given columns (the time column as text, for exact stamps) with pandas.

    Args:
        layout: The file's layout.
        indices: 0-based columns to read.
        time_index: The time column (kept as strings).

    Returns:
        A frame whose columns are labelled by their 0-based index.
    """
    for i in indices:
        if i >= layout.n_fields:
            raise input_error(f"column {i} does not exist (the first data row has "
                              f"{layout.n_fields} columns)", _COLUMNS_FIX, layout.source,
                              layout.skip + 1)
    # All columns are read (not usecols) so that a row with extra fields is an error.
    kwargs: dict = {"sep": layout.sep, "header": None, "skiprows": layout.skip, "comment": "#",
                    "dtype": {time_index: str}, "encoding": "utf-8",
                    "encoding_errors": "replace"}
    if layout.sep != WHITESPACE:
        kwargs["skipinitialspace"] = True
    if layout.decimal != ".":
        kwargs["decimal"] = layout.decimal
    try:
        frame = pd.read_csv(layout.path, **kwargs)
    except pd.errors.ParserError as err:
        m = re.search(r"line (\d+)", str(err))
        raise input_error("row does not split into the same columns as the first data row",
                          "check the delimiter and that every row has the same columns",
                          layout.source, int(m.group(1)) if m else None) from None
    except (ValueError, UnicodeError) as err:
        raise input_error(f"cannot parse the file ({err})",
                          "check that this is a delimited text file of numbers",
                          layout.source) from None
    if frame.shape[1] <= max(indices):
        raise input_error(f"column {max(indices)} does not exist (the file has "
                          f"{frame.shape[1]} columns)", _COLUMNS_FIX, layout.source,
                          layout.skip + 1)
    return frame[sorted(set(indices))]


def numeric_column(frame: pd.DataFrame, index: int, layout: Layout, lines: Lines) -> Array:
    """Column ``index`` of ``frame`` as float64, raising at the first value that is no number.

    Empty fields and ``nan`` become NaN (the stream checks decide whether that is allowed).
    """
    col = frame[index]
    if pd.api.types.is_numeric_dtype(col.dtype):
        return col.to_numpy(dtype=np.float64)
    text = col.str.replace(",", ".", regex=False) if layout.decimal == "," else col
    coerced = pd.to_numeric(text, errors="coerce")
    bad = (coerced.isna() & col.notna()).to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise lines.error(f"column {layout.label(index)} holds {col.iloc[i]!r}, not a number",
                          "fix or delete that line", i)
    return coerced.to_numpy(dtype=np.float64)


def parse_stamps(raw: pd.Series, unit: str, label: str, lines: Lines,
                 decimal: str = ".") -> IntArray:
    """Parse a time column kept as text into integer nanoseconds, exactly.

    Decimal strings (``1413394881.394290944``, ``0.0035``) are converted digit by digit, so
    float seconds keep every nanosecond; only exponent notation goes through float64.

    Args:
        raw: The column as strings (NaN where empty).
        unit: Unit of the numbers (a key of :data:`~mocap_calib.io.checks.TIME_UNITS`).
        label: Column name for messages.
        lines: Where the rows came from.
        decimal: The file's decimal mark.

    Returns:
        (N,) int64 nanoseconds.
    """
    factor = TIME_UNITS[unit]
    digits = len(str(factor)) - 1
    if len(raw) == 0:
        return np.zeros(0, dtype=np.int64)
    s = raw.astype("str").str.strip()
    if decimal != ".":
        s = s.str.replace(decimal, ".", regex=False)
    missing = (s.isna() | (s == "")).to_numpy()
    if missing.any():
        raise lines.error(f"time column {label} is empty or NaN",
                          "every row needs a timestamp; fix or delete that line",
                          int(np.flatnonzero(missing)[0]))
    plain = s.str.fullmatch(r"\d+").to_numpy(dtype=bool)
    if plain.all():
        return _scaled(_to_int64(s, unit, lines), factor, unit, lines)
    is_dec = s.str.fullmatch(r"[+-]?(\d+\.?\d*|\.\d+)").to_numpy(dtype=bool)
    out = np.zeros(len(s), dtype=np.int64)
    if is_dec.any():
        out[is_dec] = _decimal_ns(s[is_dec], factor, digits, unit, lines)
    if not is_dec.all():
        other = s[~is_dec]
        x = pd.to_numeric(other, errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(x)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise lines.error(f"time column {label} holds {other.iloc[k]!r}, not a number",
                              "fix or delete that line", int(np.flatnonzero(~is_dec)[k]))
        scaled = x * factor
        if np.any(np.abs(scaled) >= 9.2e18):
            raise lines.error(f"timestamps overflow 64-bit nanoseconds with --time-unit {unit}",
                              "check --time-unit (s, ms, us or ns)")
        out[~is_dec] = np.round(scaled).astype(np.int64)
    return out


def _to_int64(s: pd.Series, unit: str, lines: Lines) -> IntArray:
    """Digit strings to int64, raising if one does not fit."""
    n = s.str.len().to_numpy()
    if (n > 19).any() or ((n == 19) & (s > str(_INT64_MAX)).to_numpy(dtype=bool)).any():
        raise lines.error(f"timestamps overflow 64-bit nanoseconds with --time-unit {unit}",
                          "check --time-unit (s, ms, us or ns)")
    return s.astype(np.int64).to_numpy()


def _scaled(v: IntArray, factor: int, unit: str, lines: Lines) -> IntArray:
    if factor > 1 and np.any(np.abs(v) > _INT64_MAX // factor):
        raise lines.error(f"timestamps overflow 64-bit nanoseconds with --time-unit {unit}",
                          "check --time-unit (s, ms, us or ns)")
    return v * factor


def _decimal_ns(s: pd.Series, factor: int, digits: int, unit: str, lines: Lines) -> IntArray:
    """Exact ns of decimal strings ``[+-]int.frac`` (rounded half up below 1 ns)."""
    # Fast path: fixed-point columns (same number of decimals everywhere, no sign).
    length = s.str.len().to_numpy()
    dot = s.str.find(".").to_numpy()
    decimals = length - dot - 1
    if (dot > 0).all() and (decimals == decimals[0]).all() and decimals[0] <= digits \
            and not s.str.startswith(("-", "+")).any():
        v = _to_int64(s.str.replace(".", "", regex=False), unit, lines)
        return _scaled(v, factor // 10 ** int(decimals[0]), unit, lines)
    neg = s.str.startswith("-").to_numpy(dtype=bool)
    parts = s.str.lstrip("+-").str.partition(".")
    ip = _to_int64(parts[0].where(parts[0] != "", "0"), unit, lines)
    frac = parts[2]
    if digits:
        head = frac.str.slice(0, digits).str.pad(digits, side="right", fillchar="0")
        fv = head.astype(np.int64).to_numpy()
    else:
        fv = np.zeros(len(s), dtype=np.int64)
    round_up = (frac.str.slice(digits, digits + 1) >= "5").to_numpy(dtype=bool)
    ns = _scaled(ip, factor, unit, lines) + fv + round_up
    return np.where(neg, -ns, ns)


def read_indexed(layout: Layout, *, time: int, gyro: Sequence[int] | None = None,
                 accel: Sequence[int] | None = None, quat: Sequence[int] | None = None,
                 position: Sequence[int] | None = None, time_unit: str = "s",
                 gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", quat_order: str = "wxyz",
                 position_unit: str = "m", raw: bool = False
                 ) -> tuple[ImuSamples | None, MocapPoses | None]:
    """Read the streams whose (resolved, 0-based) columns are given, convert and check them.

    The building block of every reader: EuRoC and TUM call it with their fixed columns.

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
        position_unit: m or mm.
        raw: the IMU readings are raw counts: no unit conversion or check.

    Returns:
        (IMU samples or None, mocap poses or None).
    """
    check_unit(time_unit, TIME_UNITS, "--time-unit")
    check_unit(gyro_unit, GYRO_UNITS, "--gyro-unit")
    check_unit(accel_unit, ACCEL_UNITS, "--accel-unit")
    check_unit(quat_order, QUAT_ORDERS, "--quat-order")
    check_unit(position_unit, POSITION_UNITS, "--position-unit")
    indices = [time]
    for group in (gyro, accel, quat, position):
        indices += list(group or ())
    frame = read_frame(layout, indices, time)
    lines = layout.lines()
    ns = parse_stamps(frame[time], time_unit, layout.label(time), lines, layout.decimal)

    def block(cols: Sequence[int]) -> Array:
        return np.stack([numeric_column(frame, c, layout, lines) for c in cols], axis=1)

    imu = mocap = None
    if gyro is not None and accel is not None:
        g = block(gyro) * (np.pi / 180.0 if gyro_unit == "deg/s" else 1.0)
        a = block(accel) * (G0 if accel_unit == "g" else 1.0)
        imu = validate_imu(ns, g, a, lines, time_unit=time_unit, gyro_unit=gyro_unit,
                           accel_unit=accel_unit, raw=raw)
    if quat is not None and position is not None:
        q = block(quat)
        if quat_order == "xyzw":
            q = q[:, [3, 0, 1, 2]]
        p = block(position) * (1e-3 if position_unit == "mm" else 1.0)
        mocap = validate_mocap(ns, np.ascontiguousarray(q), p, lines, time_unit=time_unit,
                               position_unit=position_unit)
    return imu, mocap


def resolve_column(col: Col, layout: Layout) -> int:
    """0-based index of a column given by index or header name.

    Raises:
        InputError: if the index is out of range or the name is not in the header.
    """
    if isinstance(col, int):
        if not 0 <= col < layout.n_fields:
            raise input_error(f"column {col} does not exist (the first data row has "
                              f"{layout.n_fields} columns)", _COLUMNS_FIX, layout.source,
                              layout.skip + 1)
        return col
    if layout.names is None:
        raise input_error(f"--columns names column {col!r} but the file has no header line",
                          "use 0-based column numbers in --columns", layout.source)
    names = layout.names[: layout.n_fields]
    if col in names:
        return names.index(col)
    hits = [i for i, n in enumerate(names) if name_key(n) == name_key(col)]
    if len(hits) == 1:
        return hits[0]
    shown = ", ".join(names)
    raise input_error(f"no {'unique ' if hits else ''}column named {col!r} in the header "
                      f"({shown})", "use a header name or a 0-based index in --columns",
                      layout.source, layout.header_line)


def read_generic(path: Path | str, columns: ColumnMap | str, *, time_unit: str = "s",
                 gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", quat_order: str = "wxyz",
                 position_unit: str = "m", streams: Collection[str] | None = None,
                 raw: bool = False) -> tuple[ImuSamples | None, MocapPoses | None]:
    """Read an IMU and/or a mocap stream from a delimited text file with a column map.

    Args:
        path: The file.
        columns: A :class:`ColumnMap` or a ``--columns`` string (see the module doc).
        time_unit: Unit of the time column: s, ms, us or ns.
        gyro_unit: rad/s or deg/s.
        accel_unit: m/s^2 or g.
        quat_order: Order of the 4 quaternion columns: wxyz or xyzw.
        position_unit: m or mm.
        streams: Streams to read (``"imu"``, ``"mocap"``); each must be in the column map.
            None reads whatever the column map describes.
        raw: the IMU readings are raw counts (no unit conversion or check).

    Returns:
        (IMU samples or None, mocap poses or None), in SI units with ``[w, x, y, z]``.

    Raises:
        InputError: on any problem with the options or the file (one line, with the fix).
    """
    colmap = parse_columns(columns) if isinstance(columns, str) else columns.check()
    if streams is None:
        streams = [s for s, ok in (("imu", colmap.has_imu), ("mocap", colmap.has_mocap)) if ok]
    if "imu" in streams and not colmap.has_imu:
        raise input_error("no IMU columns (gyro= and accel=) for the IMU file", _COLUMNS_FIX,
                          "--columns")
    if "mocap" in streams and not colmap.has_mocap:
        raise input_error("no mocap columns (quat= and pos=) for the mocap file", _COLUMNS_FIX,
                          "--columns")
    if not streams:
        raise input_error("names neither IMU (gyro=, accel=) nor mocap (quat=, pos=) columns",
                          _COLUMNS_FIX, "--columns")
    layout = sniff_layout(path)

    def res(cols: tuple[Col, ...] | None, want: bool) -> list[int] | None:
        return [resolve_column(c, layout) for c in cols] if want and cols is not None else None

    return read_indexed(
        layout, time=resolve_column(colmap.time, layout),
        gyro=res(colmap.gyro, "imu" in streams), accel=res(colmap.accel, "imu" in streams),
        quat=res(colmap.quat, "mocap" in streams),
        position=res(colmap.position, "mocap" in streams),
        time_unit=time_unit, gyro_unit=gyro_unit, accel_unit=accel_unit, quat_order=quat_order,
        position_unit=position_unit, raw=raw)


# --- writing --------------------------------------------------------------------------------

def format_floats(values: Array) -> list[str]:
    """Shortest strings that parse back to exactly the same float64 (Python's ``repr``)."""
    return list(map(repr, np.asarray(values, dtype=np.float64).tolist()))


def write_table(path: Path | str, header: str, columns: Sequence[Array | IntArray | list[str]],
                sep: str = ",", chunk: int = 100_000) -> Path:
    """Write a header line and columns of numbers, deterministically and exactly.

    Integer arrays are written as integers, float arrays with :func:`format_floats`, string
    lists as they are. Rows are built with ``map``/``zip``/``join`` in chunks (no per-row Python
    code), and lines end in ``\\n`` on every platform, so the same data gives the same bytes.

    Args:
        path: Output file (parent folders are created).
        header: The header line, without newline.
        columns: Equal-length columns.
        sep: Field separator.
        chunk: Rows formatted at once (bounds memory).

    Returns:
        The path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = len(columns[0]) if columns else 0
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(header + "\n")
        for start in range(0, n, chunk):
            cols = []
            for c in columns:
                part = c[start:start + chunk]
                if isinstance(part, list):
                    cols.append(part)
                elif np.issubdtype(part.dtype, np.integer):
                    cols.append(list(map(str, part.tolist())))
                else:
                    cols.append(format_floats(part))
            f.write("\n".join(map(sep.join, zip(*cols, strict=True))))
            f.write("\n")
    return path
