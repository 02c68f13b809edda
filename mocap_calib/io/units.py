"""Unit plausibility checks of the streams: a time unit whose rate no sensor has, a gyro in
deg/s read as rad/s, an accelerometer in g, raw counts, swapped gyro and accelerometer columns,
positions in mm. One-line :class:`~mocap_calib.errors.InputError` messages naming the option
that fixes it; called by :mod:`mocap_calib.io.validate` once a stream is read and cropped."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import ACCEL_UNITS, GYRO_UNITS, POSITION_UNITS, TIME_UNITS_NS
from mocap_calib.errors import InputError


class Lines(Protocol):
    """Where a stream's rows came from (:class:`mocap_calib.io.validate.Lines`)."""

    def error(self, what: str, fix: str, row: int | None = None) -> InputError: ...


Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
TIME_UNITS = TIME_UNITS_NS
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


