"""Validation shared by every reader: one-line :class:`~mocap_calib.errors.InputError` messages.

Each message names the file, the 1-based line to blame (when one line is) and the fix. The
checks are vectorised (files can hold millions of rows); only when a check fails is the file
scanned again, in Python, to turn the offending data row into its line number (:class:`Lines`).

Readers call :func:`validate_imu` / :func:`validate_mocap` with arrays already converted to SI
units. Gaps in the IMU stamps are not refused here: the calibration bridges or splits them by
the rule in :mod:`mocap_calib.core.policy`; recording readers note them (:func:`imu_gap_note`).
:func:`check_overlap` is separate because only the calibrator knows whether a clock offset will
be searched.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.policy import (
    ACCEL_UNITS,
    GAP_FACTOR,
    GYRO_UNITS,
    IMU_TRIM_START_S,
    POSITION_UNITS,
    TIME_UNITS_NS,
    gap_threshold,
)
from mocap_calib.errors import InputError, input_error

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Nanoseconds per unit of a time column.
TIME_UNITS = TIME_UNITS_NS
QUAT_ORDERS: tuple[str, ...] = ("wxyz", "xyzw")

MIN_IMU_ROWS = 100
MIN_MOCAP_ROWS = 20
#: |q| may differ from 1 by this much before it is an error (it is then normalised).
QUAT_NORM_TOL = 1e-3
#: Below this |q| - 1 is rounding in the file: leave the numbers alone so they round-trip.
_QUAT_EXACT_TOL = 1e-12
#: Plausible sample rates (Hz) of either stream, to catch a wrong time unit.
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 1e5
#: No motion-capture system streams faster than this (Hz).
MAX_MOCAP_RATE_HZ = 1e4
TIME_NAMES = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}
#: Above this 99th percentile of |w| (rad/s) the gyro is almost surely in deg/s.
GYRO_P99_MAX = 25.0
#: If even the quietest 5 % of samples turn faster than this (rad/s), it is deg/s.
GYRO_P5_MAX = 3.0
#: Above this median |accel| (m/s^2 after the unit conversion) the readings are raw counts.
ACCEL_COUNTS_MIN = 200.0
#: A gyro faster than this (deg/s) at its 99th percentile is beyond any MEMS gyro's range.
GYRO_COUNTS_DEG_MIN = 4000.0
#: Swapped columns: the "gyro" numbers' median magnitude in this band (specific force in
#: m/s^2: real sessions 9.8-11) while the "accel" numbers' median stays below this (rates).
SWAP_FORCE = (7.0, 13.0)
SWAP_RATE_MAX = 4.0
_COUNTS_FIX = ("'mocap-calib multipos --raw' calibrates raw counts; the other commands need "
               "SI units: convert the log (or pass --gyro-unit / --accel-unit)")
_UNIT_NAMES = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}
#: Positions spanning more than this (m) in one axis are not metres.
POSITION_RANGE_MAX = 100.0


class Lines:
    """Maps 0-based data-row indices of a parsed table to 1-based lines of its file.

    The file is scanned only when an error needs a line number, so reading stays fast; a data
    line is any line after the first ``skip`` lines that is not blank and not a comment, the
    same rule the CSV parser applies.

    Args:
        source: Name of the file (or stream) for messages.
        path: The file, or None for in-memory data (messages then name no line).
        skip: Raw lines before the first data row (header, leading comments).
        comment: Comment prefix of skipped lines, or None.
    """

    def __init__(self, source: str, path: Path | None = None, skip: int = 0,
                 comment: str | None = "#", rows: IntArray | None = None) -> None:
        self.source = source
        self.path = path
        self.skip = skip
        self.comment = comment
        self.rows = rows

    def subset(self, rows: IntArray) -> Lines:
        """The map of a table cut to its rows ``rows`` (data-row indices of this map)."""
        mapped = rows if self.rows is None else self.rows[rows]
        return Lines(self.source, self.path, self.skip, self.comment, mapped)

    def line(self, row: int | None) -> int | None:
        """1-based line of data row ``row`` (None if unknown)."""
        if row is None or self.path is None:
            return None
        if self.rows is not None:
            row = int(self.rows[row])
        seen = -1
        with open(self.path, encoding="utf-8", errors="replace") as f:
            for number, text in enumerate(f, start=1):
                if number <= self.skip:
                    continue
                s = text.strip()
                if not s or (self.comment is not None and s.startswith(self.comment)):
                    continue
                seen += 1
                if seen == row:
                    return number
        return None

    def error(self, what: str, fix: str, row: int | None = None) -> InputError:
        """An :class:`InputError` naming this file and the line of data row ``row``."""
        return input_error(what, fix, self.source, self.line(row))


def check_unit(value: str, allowed: tuple[str, ...] | dict[str, int], option: str) -> str:
    """Return ``value`` if it is one of ``allowed``, else raise naming the CLI option."""
    if value not in allowed:
        choices = ", ".join(allowed)
        raise input_error(f"unknown {option} {value!r}", f"use one of: {choices}")
    return value


def _first(mask: NDArray[np.bool_]) -> int:
    return int(np.flatnonzero(mask)[0])


def require_rows(n: int, minimum: int, kind: str, lines: Lines, dropped: int = 0) -> None:
    """Raise if a stream has fewer than ``minimum`` usable rows.

    Args:
        n: Usable rows.
        minimum: Rows needed.
        kind: ``"IMU"`` or ``"mocap"``.
        lines: Where the rows came from.
        dropped: Rows already dropped as occlusions (for the message).
    """
    if n == 0:
        raise lines.error(f"no {kind} data rows (the file is empty or holds only a header)",
                          "pass the file that holds the recording")
    if n < minimum:
        extra = f" ({dropped} NaN rows dropped as occlusions)" if dropped else ""
        raise lines.error(f"only {n} usable {kind} rows{extra}; at least {minimum} are needed",
                          "record or export a longer session")


def check_increasing(ns: IntArray, kind: str, lines: Lines,
                     rows: IntArray | None = None) -> None:
    """Raise at the first timestamp that is not later than the one before it.

    Args:
        ns: Integer nanosecond stamps in file order.
        kind: ``"IMU"`` or ``"mocap"``.
        lines: Where the rows came from.
        rows: Data-row index of each stamp (None: ``0..N-1``).
    """
    if len(ns) < 2:
        return
    d = np.diff(ns)
    bad = d <= 0
    if not bad.any():
        return
    i = _first(bad) + 1
    row = int(rows[i]) if rows is not None else i
    if d[i - 1] == 0:
        raise lines.error(f"{kind} timestamp repeats the previous row's",
                          "remove duplicate rows (keep one row per timestamp)", row)
    raise lines.error(f"{kind} timestamp is earlier than the previous row's (not sorted)",
                      "sort the file by time", row)


def check_finite_imu(gyro: Array, accel: Array, lines: Lines) -> None:
    """Raise at the first IMU row holding NaN, inf or a missing value."""
    bad = ~(np.isfinite(gyro).all(axis=1) & np.isfinite(accel).all(axis=1))
    if bad.any():
        raise lines.error("IMU row has a NaN, infinite or missing value",
                          "fix or delete that row (IMU samples cannot be skipped: "
                          "re-export the IMU stream without gaps)", _first(bad))


def split_occlusions(quat: Array, position: Array, lines: Lines) -> NDArray[np.bool_]:
    """Mask of mocap rows to keep: rows with NaN (occlusions) are dropped, inf is an error.

    Returns:
        (N,) True where the pose is complete.

    Raises:
        InputError: on an infinite value, or when every row is NaN.
    """
    both = np.concatenate([quat, position], axis=1)
    inf = np.isinf(both).any(axis=1)
    if inf.any():
        raise lines.error("mocap row has an infinite value",
                          "fix that row, or write occluded poses as NaN", _first(inf))
    keep = ~np.isnan(both).any(axis=1)
    if len(keep) and not keep.any():
        raise lines.error("every mocap row is NaN (the marker body was never tracked)",
                          "check the rigid-body columns, or export a take where it is tracked")
    return keep


def normalise_quaternions(quat: Array, lines: Lines, rows: IntArray | None = None) -> Array:
    """Return unit quaternions, normalising those within :data:`QUAT_NORM_TOL` of unit norm.

    Rows whose norm is 1 up to rounding are returned bit-for-bit, so files round-trip.

    Raises:
        InputError: at the first quaternion whose norm is off by more than the tolerance.
    """
    norm = np.linalg.norm(quat, axis=1)
    off = np.abs(norm - 1.0)
    bad = off > QUAT_NORM_TOL
    if bad.any():
        i = _first(bad)
        row = int(rows[i]) if rows is not None else i
        raise lines.error(
            f"quaternion norm is {norm[i]:.6g}, not 1 (tolerance {QUAT_NORM_TOL:g})",
            "check that the quaternion columns are the right ones, or normalise them "
            "(write occluded poses as NaN, not zeros)", row)
    fix = off > _QUAT_EXACT_TOL
    if fix.any():
        quat = quat.copy()
        quat[fix] /= norm[fix, None]
    return quat


def time_unit_hint(raw_step: float, declared: str, kind: str = "IMU"
                   ) -> tuple[str, float] | None:
    """The time unit (other than ``declared``) in which samples ``raw_step`` apart (in the
    file's own numbers) have a plausible rate for the stream, with that rate; the most typical
    rate (near 300 Hz) wins when several fit (they are 1000x apart). None if none fits."""
    if not (np.isfinite(raw_step) and raw_step > 0):
        return None
    top = MAX_MOCAP_RATE_HZ if kind == "mocap" else MAX_RATE_HZ
    fits = [(u, 1e9 / (raw_step * f)) for u, f in TIME_UNITS.items() if u != declared]
    fits = [(u, r) for u, r in fits if MIN_RATE_HZ <= r <= top]
    if not fits:
        return None
    return min(fits, key=lambda ur: abs(np.log10(ur[1]) - 2.5))


def check_time_unit(ns: IntArray, unit: str, kind: str, lines: Lines) -> None:
    """Raise if the median sample spacing implies an implausible rate for the declared unit.

    Args:
        ns: Sorted integer nanosecond stamps (after the unit conversion).
        unit: Declared time unit of the column (a key of :data:`TIME_UNITS`).
        kind: ``"IMU"`` or ``"mocap"``.
        lines: Where the rows came from.
    """
    if len(ns) < 2:
        return
    step_ns = float(np.median(np.diff(ns)))
    if step_ns <= 0:
        return
    rate = 1e9 / step_ns
    top = MAX_MOCAP_RATE_HZ if kind == "mocap" else MAX_RATE_HZ
    if MIN_RATE_HZ <= rate <= top:
        return
    hint = time_unit_hint(step_ns / TIME_UNITS[unit], unit, kind)
    what = (f"{kind} samples are {step_ns * 1e-9:.3g} s apart ({rate:.3g} Hz) if the "
            f"timestamps are in {unit}, which is implausible")
    if hint:
        best, best_rate = hint
        fix = (f"the timestamps look like {best} ({TIME_NAMES[best]}, {best_rate:.3g} Hz); pass "
               f"--time-unit {best} (or convert this file's stamps to {unit} if the other "
               f"file's are in {unit})")
    else:
        fix = "check the time column and --time-unit (s, ms, us or ns)"
    raise lines.error(what, fix)


def imu_gaps(t: Array) -> tuple[IntArray, Array]:
    """Gaps of an IMU stream by the one gap rule (:func:`~mocap_calib.core.policy.gap_threshold`):
    the index ``i`` of the sample before each gap (the gap is ``t[i]..t[i+1]``) and its length
    (s). The readers report gaps; what is done with them is the calibration's business."""
    if len(t) < 3:
        return np.zeros(0, np.int64), np.zeros(0)
    d = np.diff(t)
    i = np.flatnonzero(d > gap_threshold(t))
    return i, d[i]


def imu_gap_note(t: Array, source: str) -> str | None:
    """One line on the gaps in the IMU stamps ``t`` (s from the IMU start), None if none."""
    i, length = imu_gaps(t)
    if len(i) == 0:
        return None
    k = int(np.argmax(length))
    step = float(np.median(np.diff(t)))
    start = (f"; the first at {t[i[0]]:.3f} s, at the logger start" if t[i[0]] - t[0]
             <= IMU_TRIM_START_S else "")
    return (f"{source}: {len(i)} gap{'s' if len(i) > 1 else ''} in the IMU stamps (steps over "
            f"{GAP_FACTOR:g}x the median {step * 1e3:.3g} ms): longest {length[k]:.3f} s at "
            f"{t[i[k]]:.3f} s from the IMU start, {float(length.sum()):.3f} s in all{start}")


def _integral(x: Array) -> bool:
    return bool(np.all(x == np.round(x)))


def check_swapped(gyro: Array, accel: Array, gyro_unit: str, accel_unit: str,
                  lines: Lines) -> None:
    """Raise when the gyro and accel columns look swapped: the "gyro" reads like specific
    force (median magnitude near |g| in m/s^2, never near zero, as rates often are) and the
    "accel" far below |g|. Checked before the units, whose hints would mislead here."""
    g = np.linalg.norm(gyro / GYRO_UNITS[gyro_unit], axis=1)  # the file's numbers
    a = np.linalg.norm(accel / ACCEL_UNITS[accel_unit], axis=1)
    g5, gm = (float(v) for v in np.percentile(g, [5.0, 50.0]))
    am = float(np.median(a))
    if not (SWAP_FORCE[0] <= gm <= SWAP_FORCE[1] and g5 > 0.4 * gm and am < SWAP_RATE_MAX):
        return
    fix = ("swap them: gyro x y z first, then accel x y z (EuRoC imu0 layout); with --columns, "
           "exchange the gyro= and accel= columns")
    if 0.85 <= am <= 1.15:  # also the numbers of a slow deg/s gyro and an accel in g
        fix += " (or, if the gyro is in deg/s and the accelerometer in g: pass --gyro-unit " \
               "deg/s --accel-unit g)"
    raise lines.error(f"the gyro and accelerometer columns look swapped: the gyro columns read "
                      f"like specific force (median magnitude {gm:.3g}, near |g| = 9.81 m/s^2, "
                      f"and never near 0) and the accelerometer columns like rates (median "
                      f"{am:.3g})", fix)


def check_imu_units(gyro: Array, accel: Array, gyro_unit: str, accel_unit: str,
                    lines: Lines) -> None:
    """Raise when gyro or accel magnitudes suggest a unit other than the declared one; raw
    sensor counts are named as such (never taken for deg/s).

    Args:
        gyro: (N, 3) rates converted to rad/s with ``gyro_unit``.
        accel: (N, 3) specific force converted to m/s^2 with ``accel_unit``.
        gyro_unit: Declared gyro unit.
        accel_unit: Declared accel unit.
        lines: Where the rows came from.
    """
    a = float(np.median(np.linalg.norm(accel, axis=1)))
    if a > ACCEL_COUNTS_MIN:
        raise lines.error(f"IMU readings look like raw sensor counts (median accelerometer "
                          f"magnitude {a:.4g}, far above |g| in any unit)", _COUNTS_FIX)
    if accel_unit == "m/s^2" and 0.5 <= a <= 2.0:
        raise lines.error(f"median accelerometer magnitude is {a:.3g} m/s^2",
                          "the accelerometer looks like it is in g; pass --accel-unit g")
    if accel_unit == "g" and 50.0 <= a <= 200.0:
        raise lines.error(f"median accelerometer magnitude is {a:.3g} m/s^2 after converting "
                          "from g", "the accelerometer looks like it is already in m/s^2; "
                          "pass --accel-unit m/s^2")
    w = np.linalg.norm(gyro, axis=1)
    p5, p99 = (float(v) for v in np.percentile(w, [5.0, 99.0]))
    figures = f"99th percentile {p99:.3g} rad/s, 5th percentile {p5:.3g} rad/s"
    as_deg = p99 if gyro_unit == "rad/s" else float(np.degrees(p99))  # the file's numbers
    if as_deg > GYRO_COUNTS_DEG_MIN:
        # Read as deg/s these would still turn faster than any gyro can: counts, not deg/s.
        raise lines.error(f"gyro magnitudes are implausible in {gyro_unit} ({figures}) and "
                          "in deg/s alike: they look like raw sensor counts", _COUNTS_FIX)
    if gyro_unit == "rad/s" and (p99 > GYRO_P99_MAX or p5 > GYRO_P5_MAX):
        if _integral(gyro) and _integral(accel):
            raise lines.error(f"gyro magnitudes are implausible in rad/s ({figures}) and all "
                              "readings are integers: they look like raw sensor counts",
                              _COUNTS_FIX)
        raise lines.error(f"gyro magnitudes are implausible in rad/s ({figures})",
                          "the gyro looks like it is in deg/s; pass --gyro-unit deg/s")


def check_position_unit(position: Array, position_unit: str, lines: Lines) -> None:
    """Raise when positions (converted to metres) span more than a mocap room could."""
    if position_unit != "m" or len(position) == 0:
        return
    span = float(np.max(np.ptp(position, axis=0)))
    if span > POSITION_RANGE_MAX:
        # The span alone cannot tell centimetres from millimetres: name every unit that
        # gives a room-sized span; calibrate's convention check says which one the
        # accelerometer agrees with.
        fits = [(u, span * m) for u, m in POSITION_UNITS.items()
                if u != "m" and 0.1 <= span * m <= POSITION_RANGE_MAX]
        if fits:
            shown = " or ".join(f"{_UNIT_NAMES[u]} (a {s:.3g} m span)" for u, s in fits)
            fix = ("pass " + " or ".join(f"--position-unit {u}" for u, _ in fits)
                   + (", whichever the file uses" if len(fits) > 1 else ""))
            what = f"positions span {span:.4g} m, more than a mocap volume: not metres; {shown}"
        else:
            what = f"positions span {span:.4g} m, more than a mocap volume, in any unit"
            fix = "check the position columns"
        raise lines.error(what, fix)


def validate_imu(ns: IntArray, gyro: Array, accel: Array, lines: Lines, *,
                 time_unit: str = "ns", gyro_unit: str = "rad/s",
                 accel_unit: str = "m/s^2", raw: bool = False,
                 origin_ns: int | None = None) -> ImuSamples:
    """Check a parsed IMU table and build :class:`ImuSamples` from it.

    Args:
        ns: (N,) integer nanosecond stamps, file order.
        gyro: (N, 3) rad/s.
        accel: (N, 3) m/s^2.
        lines: Where the rows came from (also the samples' ``source``).
        time_unit: Unit the file's time column was declared in (for hints).
        gyro_unit: Declared gyro unit (for hints).
        accel_unit: Declared accel unit (for hints).
        raw: the readings are raw counts (no unit check).
        origin_ns: The stamp of ``t == 0`` (None: the first stamp).

    Returns:
        The samples, times relative to ``origin_ns``.
    """
    if len(ns) == 0:
        require_rows(0, MIN_IMU_ROWS, "IMU", lines)
    check_finite_imu(gyro, accel, lines)
    check_increasing(ns, "IMU", lines)
    require_rows(len(ns), MIN_IMU_ROWS, "IMU", lines)
    check_time_unit(ns, time_unit, "IMU", lines)
    if not raw:
        check_swapped(gyro, accel, gyro_unit, accel_unit, lines)
        check_imu_units(gyro, accel, gyro_unit, accel_unit, lines)
    origin = int(ns[0]) if origin_ns is None else origin_ns
    return ImuSamples((ns - origin) / 1e9, gyro, accel, origin, lines.source)


def validate_mocap(ns: IntArray, quat_wxyz: Array, position: Array, lines: Lines, *,
                   time_unit: str = "ns", position_unit: str = "m",
                   origin_ns: int | None = None) -> MocapPoses:
    """Check a parsed mocap table, drop NaN rows (occlusions) and build :class:`MocapPoses`.

    Args:
        ns: (N,) integer nanosecond stamps, file order.
        quat_wxyz: (N, 4) quaternions ``R_WM``, [w, x, y, z].
        position: (N, 3) metres.
        lines: Where the rows came from (also the poses' ``source``).
        time_unit: Unit the file's time column was declared in (for hints).
        position_unit: Declared position unit (for hints).
        origin_ns: The stamp of ``t == 0`` (None: the first complete pose's).

    Returns:
        The complete poses, ``dropped_rows`` counting the NaN rows removed.
    """
    if len(ns) == 0:
        require_rows(0, MIN_MOCAP_ROWS, "mocap", lines)
    keep = split_occlusions(quat_wxyz, position, lines)
    check_increasing(ns, "mocap", lines)
    rows = np.flatnonzero(keep)
    ns, quat_wxyz, position = ns[keep], quat_wxyz[keep], position[keep]
    quat_wxyz = normalise_quaternions(quat_wxyz, lines, rows)
    require_rows(len(ns), MIN_MOCAP_ROWS, "mocap", lines, dropped=len(keep) - len(rows))
    check_time_unit(ns, time_unit, "mocap", lines)
    check_position_unit(position, position_unit, lines)
    origin = int(ns[0]) if origin_ns is None else origin_ns
    return MocapPoses((ns - origin) / 1e9, quat_wxyz, position, origin, lines.source,
                      dropped_rows=int(len(keep) - len(rows)),
                      position_unit_m=POSITION_UNITS.get(position_unit, 1.0))


def check_overlap(imu: ImuSamples, mocap: MocapPoses, allow_offset: bool,
                  min_overlap_s: float = 1.0) -> float:
    """Check that the two streams cover a common stretch of absolute time.

    Absolute time is ``time_origin_ns + t`` on each stream's clock. Without a time-offset
    model the clocks must agree, so the spans must overlap; with one (``allow_offset``) the
    calibrator searches the offset and no overlap is required.

    Args:
        imu: The IMU samples.
        mocap: The mocap poses.
        allow_offset: The model estimates ``time_offset``.
        min_overlap_s: Overlap needed (s) when ``allow_offset`` is False.

    Returns:
        The overlap in seconds (negative: the gap between the spans).

    Raises:
        InputError: when the overlap is shorter than ``min_overlap_s`` and no offset is searched.
    """
    a = imu.stamps_ns()
    b = mocap.stamps_ns()
    if len(a) == 0 or len(b) == 0:
        return 0.0
    overlap = (min(int(a[-1]), int(b[-1])) - max(int(a[0]), int(b[0]))) * 1e-9
    if overlap >= min_overlap_s or allow_offset:
        return overlap
    what = (f"the IMU ({imu.source}, {a[0] * 1e-9:.3f}..{a[-1] * 1e-9:.3f} s) and mocap "
            f"({mocap.source}, {b[0] * 1e-9:.3f}..{b[-1] * 1e-9:.3f} s) time spans "
            + ("do not overlap" if overlap <= 0 else f"overlap by only {overlap:.3g} s"))
    raise input_error(what, "add --model base+time_offset (which searches the clock offset) "
                      "or fix the clocks so both streams share one time base")
