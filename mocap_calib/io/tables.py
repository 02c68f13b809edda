"""Writing tables of numbers: deterministic bytes, floats that parse back exactly."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.io.atomic import write_with

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
    # Atomic (io/atomic.py): an interrupted run leaves the old file (or none), never half.
    return write_with(path, lambda tmp: _write_rows(tmp, header, columns, sep, chunk))


def _write_rows(path: Path, header: str, columns: Sequence[Array | IntArray | list[str]],
                sep: str, chunk: int) -> None:
    n = len(columns[0]) if columns else 0
    with open(path, "x", encoding="utf-8", newline="\n") as f:
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
