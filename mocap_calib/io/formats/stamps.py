"""Time columns kept as text, parsed into exact integer nanoseconds."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import InputError
from mocap_calib.io.formats.layout import NA_CELLS
from mocap_calib.io.units import TIME_NAMES, time_unit_hint
from mocap_calib.io.validate import TIME_UNITS, Lines

IntArray = NDArray[np.int64]
Text = NDArray[np.str_]
_INT64_MAX = np.iinfo(np.int64).max


def parse_stamps(raw: Text, unit: str, label: str, lines: Lines,
                 decimal: str = ".") -> IntArray:
    """Parse a time column kept as text into integer nanoseconds, exactly.

    Decimal strings (``1413394881.394290944``, ``0.0035``) are converted digit by digit, so
    float seconds keep every nanosecond; only exponent notation goes through float64.

    Args:
        raw: The column's cells as text ("" where empty).
        unit: Unit of the numbers (a key of :data:`~mocap_calib.io.validate.TIME_UNITS`).
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
    fixed = _fixed_width_digits(raw)
    if fixed is not None:
        return _scaled(fixed, factor, unit, lines)
    s = np.strings.strip(np.asarray(raw, dtype=str), ' \t\r\n\v\f"')  # spaces and quotes
    if decimal != ".":
        s = np.strings.replace(s, decimal, ".")
    missing = np.isin(s, list(NA_CELLS))
    if missing.any():
        raise lines.error(f"time column {label} is empty or NaN",
                          "every row needs a timestamp; fix or delete that line",
                          int(np.flatnonzero(missing)[0]))
    if _digits(s).all():
        return _scaled(_to_int64(s, unit, lines), factor, unit, lines)
    if unit == "ns":
        _refuse_fractional_ns(s, label, lines)
    sign = np.strings.startswith(s, "-") | np.strings.startswith(s, "+")
    ip, dot, fp = np.strings.partition(np.where(sign, np.strings.slice(s, 1, None), s), ".")
    has_i, has_f = ip != "", fp != ""
    is_dec = ((_digits(ip) | ~has_i) & (_digits(fp) | ~has_f) & (has_i | has_f)
              & (has_i | (dot != "")))
    out = np.zeros(len(s), dtype=np.int64)
    if is_dec.any():
        out[is_dec] = _decimal_ns(s[is_dec], factor, digits, unit, lines)
    if not is_dec.all():
        other = s[~is_dec]
        x = _floats(other)
        bad = ~np.isfinite(x)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise lines.error(f"time column {label} holds {str(other[k])!r}, not a number",
                              "fix or delete that line", int(np.flatnonzero(~is_dec)[k]))
        scaled = x * factor
        if np.any(np.abs(scaled) >= 9.2e18):
            raise _overflow(s, unit, lines)
        out[~is_dec] = np.round(scaled).astype(np.int64)
    return out


def _fixed_width_digits(raw: Text) -> IntArray | None:
    """The usual time column at once: every cell the same number of ASCII digits (at most 19,
    within int64), read from the characters' codes (None: any other column, left to the
    general path, which also names an overflow)."""
    raw = np.asarray(raw)
    width = raw.dtype.itemsize // 4
    if raw.dtype.kind != "U" or raw.ndim != 1 or not 0 < width <= 19:
        return None
    codes = np.ascontiguousarray(raw).view(np.uint32).reshape(len(raw), width)
    if not ((codes >= 48) & (codes <= 57)).all():  # also a shorter cell (NUL padding)
        return None
    if width == 19:
        high = codes[:, 0] == 57
        if high.any() and (raw[high] > str(_INT64_MAX)).any():
            return None
    # Exact in int64: the digits below the cut are under 1e9, those above under 1e10.
    digits = (codes - 48).astype(np.int64)
    low = min(width, 9)
    value = digits[:, width - low:] @ 10 ** np.arange(low - 1, -1, -1, dtype=np.int64)
    if width > low:
        value += (digits[:, :width - low] @ 10 ** np.arange(width - low - 1, -1, -1,
                                                            dtype=np.int64)) * 10**9
    return value


def _digits(s: Text) -> NDArray[np.bool_]:
    """Cells of decimal digits only (not empty)."""
    return np.strings.isdecimal(s)


def _floats(s: Text) -> NDArray[np.float64]:
    """Cells as float64, NaN where a cell is no number."""
    out = np.full(len(s), np.nan)
    for i, cell in enumerate(s.tolist()):
        try:
            out[i] = float(cell) if "_" not in cell else np.nan
        except ValueError:
            pass
    return out


def _to_int64(s: Text, unit: str, lines: Lines) -> IntArray:
    """Digit strings to int64, raising if one does not fit."""
    n = np.strings.str_len(s)
    if (n > 19).any() or ((n == 19) & (s > str(_INT64_MAX))).any():
        raise _overflow(s, unit, lines)
    return s.astype(np.int64)


def _scaled(v: IntArray, factor: int, unit: str, lines: Lines) -> IntArray:
    if factor > 1 and np.any(np.abs(v) > _INT64_MAX // factor):
        raise _overflow(v.astype(str), unit, lines)
    return v * factor


def _decimal_ns(s: Text, factor: int, digits: int, unit: str, lines: Lines) -> IntArray:
    """Exact ns of decimal strings ``[+-]int.frac`` (rounded half up below 1 ns)."""
    # Fast path: fixed-point columns (same number of decimals everywhere, no sign).
    length = np.strings.str_len(s)
    dot = np.strings.find(s, ".")
    decimals = length - dot - 1
    neg = np.strings.startswith(s, "-")
    if (dot > 0).all() and (decimals == decimals[0]).all() and decimals[0] <= digits \
            and not (neg | np.strings.startswith(s, "+")).any():
        v = _to_int64(np.strings.replace(s, ".", ""), unit, lines)
        return _scaled(v, factor // 10 ** int(decimals[0]), unit, lines)
    ip, _, frac = np.strings.partition(np.strings.lstrip(s, "+-"), ".")
    ip = _to_int64(np.where(ip == "", "0", ip), unit, lines)
    if digits:
        head = np.strings.ljust(np.strings.slice(frac, 0, digits), digits, "0")
        fv = head.astype(np.int64)
    else:
        fv = np.zeros(len(s), dtype=np.int64)
    round_up = np.strings.slice(frac, digits, digits + 1) >= "5"
    ns = _scaled(ip, factor, unit, lines) + fv + round_up
    return np.where(neg, -ns, ns)


def _hint(s: Text, unit: str) -> str:
    """`` they look like X (R Hz): pass --time-unit X`` from the numbers' own spacing."""
    x = _floats(s)
    x = x[np.isfinite(x)]
    step = float(np.median(np.diff(x))) if len(x) > 1 else float("nan")
    hint = time_unit_hint(step, unit)
    if hint is None:
        return "check the time column and --time-unit (s, ms, us or ns)"
    u, rate = hint
    return f"they look like {u} ({TIME_NAMES[u]}, {rate:.3g} Hz): pass --time-unit {u}"


def _overflow(s: Text, unit: str, lines: Lines) -> InputError:
    """The error for stamps that do not fit 64-bit nanoseconds, naming the likely unit (or
    the absurd stamp)."""
    digits = np.strings.str_len(np.strings.partition(np.strings.lstrip(s, "+-"), ".")[0])
    if digits.max() > 25:
        row = int(np.argmax(digits))
        return lines.error(f"a timestamp has {int(digits[row])} digits, more than any time in "
                           "s, ms, us or ns", "fix or delete that line", row)
    return lines.error(f"timestamps overflow 64-bit nanoseconds if they are in {unit} "
                       f"({TIME_NAMES[unit]})", _hint(s, unit))


def _refuse_fractional_ns(s: Text, label: str, lines: Lines) -> None:
    """Nanosecond stamps are integers: decimals with a fraction mean another unit."""
    frac = np.strings.strip(np.strings.partition(s, ".")[2], "0")
    bad = np.strings.str_len(frac) > 0
    if bad.any():
        raise lines.error(f"time column {label} holds {str(s[int(np.argmax(bad))])!r}: "
                          "nanosecond stamps are whole numbers, these have decimals",
                          _hint(s, "ns"), int(np.argmax(bad)))
