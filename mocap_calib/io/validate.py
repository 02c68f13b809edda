"""Validation shared by every reader: one-line :class:`~mocap_calib.errors.InputError` messages.

Each message names the file, the 1-based line to blame (when one line is) and the fix. The
checks are vectorised (files can hold millions of rows); only when a check fails is the file
scanned again, in Python, to turn the offending data row into its line number (:class:`Lines`).

Readers hand tables (:mod:`mocap_calib.io.streams`) to the loader, which crops them and calls
:func:`validate_imu` / :func:`validate_mocap` with arrays already converted to SI units (the
unit plausibility checks are in :mod:`mocap_calib.io.units`). Gaps in the IMU stamps are not
refused here: the calibration bridges or splits them by the rule in
:mod:`mocap_calib.core.policy`; recording readers note them (:func:`imu_gap_note`).
:func:`check_overlap` is separate because only the calibrator knows whether a clock offset will
be searched.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.policy import (
    GAP_FACTOR,
    IMU_TRIM_START_S,
    POSITION_UNITS,
    TIME_UNITS_NS,
    gap_threshold,
)
from mocap_calib.errors import InputError, input_error
from mocap_calib.io.units import (
    check_imu_units,
    check_position_unit,
    check_swapped,
    check_time_unit,
)

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
#: Slowest mocap a calibration reads (Hz). The position windows need 20 poses in 5 s (4 Hz);
#: the clock search compares the gyro's angular speed with the mocap's, and a 10 Hz stream
#: (Nyquist 5 Hz) holds 96-97 % of the angular speed's variance of the real EuRoC V2_03 and
#: BROAD 21 sessions (90 % at 5 Hz). Measured on simulated 60 s flights: 5 Hz still calibrates
#: (within 1.3 sigma), 2-3 Hz stops with a misleading "no match at any clock offset" or
#: "fewer than 2 gap-free windows"; 10 Hz keeps a factor of 2 for faster real motion.
MIN_MOCAP_RATE_HZ = 10.0
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
    reset = _clock_reset(ns, d, i, kind)
    if reset is not None:
        raise lines.error(*reset, row)
    raise lines.error(f"{kind} timestamp is earlier than the previous row's (not sorted)",
                      "sort the file by time", row)


#: A step back longer than this many median steps, followed by increasing stamps, is a clock
#: reset (two stretches of the log), not rows out of order.
RESET_STEPS = 10


def _clock_reset(ns: IntArray, d: IntArray, i: int, kind: str) -> tuple[str, str] | None:
    """(what, fix) when the step back before row ``i`` is a clock reset, else None."""
    ahead = d[i:i + RESET_STEPS]
    forward = d[d > 0]
    step = float(np.median(forward)) if len(forward) else 0.0
    if not (step > 0 and -d[i - 1] > RESET_STEPS * step and np.all(ahead > 0)):
        return None
    before, after = (ns[i - 1] - ns[0]) * 1e-9, (ns[i] - ns[0]) * 1e-9
    what = (f"the {kind} clock resets here: the stamps go back by {before - after:.3f} s, from "
            f"{before:.3f} s to {after:.3f} s after the first row, and run on from there (two "
            "stretches of the log, not rows out of order)")
    fix = "split the file into two takes at this line (each as its own --imu/--mocap pair)"
    if kind == "IMU":
        crops = [f"--end {after - step * 1e-9:.3f}" if after - step * 1e-9 > 0 else "",
                 f"--start {before + step * 1e-9:.3f}" if (ns[-1] - ns[0]) * 1e-9 > before
                 else ""]
        crops = [c for c in crops if c]
        if crops:
            fix += f", or crop to one side of it with {' or '.join(crops)}"
    return what, fix


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


def check_mocap_rate(mocap: MocapPoses, minimum_hz: float) -> None:
    """Raise when the mocap's median rate is below ``minimum_hz`` (:data:`MIN_MOCAP_RATE_HZ`)."""
    rate = mocap.rate_hz
    if rate >= minimum_hz:
        return
    raise input_error(f"the mocap streams at {rate:.3g} Hz (median step "
                      f"{1e3 / rate if rate > 0 else float('inf'):.0f} ms); the calibration "
                      f"needs at least {minimum_hz:g} Hz to follow the motion between poses",
                      "record (or export) the poses at a higher rate, e.g. 100 Hz; if the "
                      "stamps are in another unit than read, pass --time-unit",
                      mocap.source)


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
