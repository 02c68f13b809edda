"""Time columns kept as text, parsed into exact integer nanoseconds."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import InputError
from mocap_calib.io.checks import TIME_NAMES, TIME_UNITS, Lines, time_unit_hint
from mocap_calib.io.pandas_csv import pd

IntArray = NDArray[np.int64]
_INT64_MAX = np.iinfo(np.int64).max


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
    if unit == "ns":
        _refuse_fractional_ns(s, label, lines)
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
            raise _overflow(s, unit, lines)
        out[~is_dec] = np.round(scaled).astype(np.int64)
    return out


def _to_int64(s: pd.Series, unit: str, lines: Lines) -> IntArray:
    """Digit strings to int64, raising if one does not fit."""
    n = s.str.len().to_numpy()
    if (n > 19).any() or ((n == 19) & (s > str(_INT64_MAX)).to_numpy(dtype=bool)).any():
        raise _overflow(s, unit, lines)
    return s.astype(np.int64).to_numpy()


def _scaled(v: IntArray, factor: int, unit: str, lines: Lines) -> IntArray:
    if factor > 1 and np.any(np.abs(v) > _INT64_MAX // factor):
        raise _overflow(pd.Series(v.astype(str)), unit, lines)
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


def _hint(s: pd.Series, unit: str) -> str:
    """`` they look like X (R Hz): pass --time-unit X`` from the numbers' own spacing."""
    x = pd.to_numeric(s, errors="coerce").to_numpy(dtype=np.float64)
    x = x[np.isfinite(x)]
    step = float(np.median(np.diff(x))) if len(x) > 1 else float("nan")
    hint = time_unit_hint(step, unit)
    if hint is None:
        return "check the time column and --time-unit (s, ms, us or ns)"
    u, rate = hint
    return f"they look like {u} ({TIME_NAMES[u]}, {rate:.3g} Hz): pass --time-unit {u}"


def _overflow(s: pd.Series, unit: str, lines: Lines) -> InputError:
    """The error for stamps that do not fit 64-bit nanoseconds, naming the likely unit (or
    the absurd stamp)."""
    digits = s.str.lstrip("+-").str.partition(".")[0].str.len().to_numpy()
    if digits.max() > 25:
        row = int(np.argmax(digits))
        return lines.error(f"a timestamp has {int(digits[row])} digits, more than any time in "
                           "s, ms, us or ns", "fix or delete that line", row)
    return lines.error(f"timestamps overflow 64-bit nanoseconds if they are in {unit} "
                       f"({TIME_NAMES[unit]})", _hint(s, unit))


def _refuse_fractional_ns(s: pd.Series, label: str, lines: Lines) -> None:
    """Nanosecond stamps are integers: decimals with a fraction mean another unit."""
    frac = s.str.partition(".")[2].str.strip("0")
    bad = (frac.str.len() > 0).to_numpy()
    if bad.any():
        raise lines.error(f"time column {label} holds {s.iloc[int(np.argmax(bad))]!r}: "
                          "nanosecond stamps are whole numbers, these have decimals",
                          _hint(s, "ns"), int(np.argmax(bad)))
