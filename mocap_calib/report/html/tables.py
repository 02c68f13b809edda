"""Table helpers shared by the report pages: numbers shown to their sigma's precision, each cell
tied to its key in the result file."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from mocap_calib.report.html.page import Cell


def value_text(v: float, sigma: float | None = None) -> str:
    """``v`` with as many decimals as two significant digits of ``sigma`` need (6 significant
    digits without a sigma)."""
    if not np.isfinite(v):
        return "-"
    if sigma is None or not np.isfinite(sigma) or not sigma > 0:
        return f"{v:.6g}"
    decimals = int(np.clip(1 - np.floor(np.log10(sigma)), 0, 12))
    return f"{v:.{decimals}f}"


def num(key: str, v: Any, scale: float = 1.0, sigma: float | None = None,
        digits: int | None = None) -> Cell:
    """A numeric cell for the file's value ``v`` at ``key``, shown times ``scale``."""
    if v is None:
        return Cell("-", key, "null", scale)
    if isinstance(v, (bool, np.bool_)):
        return Cell(str(bool(v)).lower(), key, str(bool(v)).lower())
    if isinstance(v, str):
        return Cell(v, key, v)
    x = float(v) * scale
    text = f"{x:.{digits}g}" if digits is not None else value_text(
        x, None if sigma is None else abs(sigma * scale))
    return Cell(text, key, float(v), scale)


def flat(value: Any, key: str) -> Iterator[tuple[str, Any]]:
    """(key path, scalar) for every scalar in nested lists/dicts, e.g. ``a/0/1``."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            yield from flat(v, f"{key}/{k}")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from flat(v, f"{key}/{i}")
    else:
        yield key, value


def get(d: Mapping[str, Any], key: str) -> Any:
    """The value at a key path (``/`` between keys and list indices), or None."""
    cur: Any = d
    for part in key.split("/"):
        if isinstance(cur, Mapping):
            cur = cur.get(part)
        elif isinstance(cur, (list, tuple)) and part.lstrip("-").isdigit():
            cur = cur[int(part)] if -len(cur) <= int(part) < len(cur) else None
        else:
            return None
        if cur is None:
            return None
    return cur


def kv_rows(d: Mapping[str, Any], prefix: str, digits: int = 4) -> list[list[str | Cell]]:
    """One row per scalar of a nested dict: (key, value)."""
    rows: list[list[str | Cell]] = []
    for key, v in flat(d, prefix):
        label = key[len(prefix) + 1:] if key.startswith(prefix + "/") else key
        plain = isinstance(v, (int, float, bool, str, np.bool_, np.number)) or v is None
        rows.append([label, num(key, v if plain else str(v), digits=digits)])
    return rows
