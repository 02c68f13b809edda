"""Tables of numbers as text: written with deterministic bytes and floats that parse back
exactly; large plain CSV files read with pyarrow's parser (for
:func:`mocap_calib.io.formats.layout.read_table`)."""

from __future__ import annotations

import codecs
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.io.atomic import write_with

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
Text = NDArray[np.str_]


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


# --- large plain CSV files, read with pyarrow -------------------------------------------------
#
# On a file of tens of MB, read_table's own path (io/formats/layout.py) spends most of its time
# in Python string handling around numpy's C parser (splitting the lines, cutting comments,
# taking the time column's text). pyarrow's parser reads the same rows several times faster, and
# its numbers are the same bits (both round every decimal string correctly).
#
# Only plain files take this path: at least PYARROW_MIN_BYTES long, separated by "," or ";" with
# "." decimals, without a byte order mark or a CR in the header part, and whose data rows hold
# nothing but digits, ".", "+", "-", "e", "E", the separator and "\n" (no comment, quote, space,
# tab, CR, NA or other word). Any other file, and any file whose rows pyarrow refuses (an empty
# cell, a row of another length, a cell that is no number), gives None: read_table then reads it
# its own way, so its tables and messages do not change. pyarrow is imported only when such a
# file is read.

#: Files from this size up are read with pyarrow (when plain). Importing it costs ~0.05 s and
#: ~28 MiB of resident memory kept to the end of the process; the numpy path takes ~12 ms a MB,
#: pyarrow's ~4 ms a MB: it saves time from ~6 MB, and the recorded sessions (2-4 MB a file)
#: keep their peak memory.
PYARROW_MIN_BYTES = 8 * 2**20

#: The bytes of a number (the separator and ``\n`` are added per file).
_NUMBER_BYTES = b"0123456789.+-eE"
_SCAN_BYTES = 2**20


def read_plain(path: Path, skip: int, sep: str | None, decimal: str, n_fields: int,
               numeric: Collection[int], text: Collection[int]
               ) -> tuple[dict[int, Array], dict[int, Text]] | None:
    """The columns of a large plain file, as the line-by-line reader would give them.

    Args:
        path: The file.
        skip: Raw lines before the first data row.
        sep: The delimiter (None: runs of whitespace, never read here).
        decimal: The decimal mark (only ``.`` is read here).
        n_fields: Fields of the first data row; every row must have as many.
        numeric: Columns wanted as float64.
        text: Columns wanted as text.

    Returns:
        (numbers by column, text by column), or None when the file is small or not plain, or
        pyarrow refuses it: then read it the usual way.
    """
    if sep not in (",", ";") or decimal != "." or n_fields < 1:
        return None
    raw = _plain_bytes(path, skip, sep)
    if raw is None:
        return None
    data, start = raw
    import pyarrow as pa  # only here: ~28 MiB resident (see PYARROW_MIN_BYTES)

    try:
        table = _arrow_table(pa, memoryview(data)[start:], sep, n_fields, text)
    except (pa.ArrowException, ValueError):
        return None  # an empty cell, a row of another length, a cell that is no number
    del data, raw
    if table.num_rows == 0 or table.num_columns != n_fields:
        return None
    cells = {c: _text(table.column(c)) for c in text}
    numbers: dict[int, Array] = {}
    for c in sorted(set(numeric)):
        if c in cells:
            values = _text_numbers(cells[c])
            if values is None:
                return None
            numbers[c] = values
        else:
            numbers[c] = _floats(table.column(c))
    return numbers, {c: cells[c][1] for c in text}


def _plain_bytes(path: Path, skip: int, sep: str) -> tuple[bytearray, int] | None:
    """The file's bytes and where its data rows start, if it is large and plain (read and
    checked by blocks: a file that is not plain is often found out early)."""
    allowed = _NUMBER_BYTES + sep.encode() + b"\n"
    try:
        size = path.stat().st_size
        if size < PYARROW_MIN_BYTES:
            return None
        data = bytearray(size)
        view = memoryview(data)
        start = -1
        with open(path, "rb") as f:
            for i in range(0, size, _SCAN_BYTES):
                block = view[i:i + _SCAN_BYTES]
                if f.readinto(block) != len(block):
                    return None  # the file changed while read
                if start < 0:
                    start = _data_start(data, skip)
                    if start < 0:
                        return None
                if data[max(i, start):i + _SCAN_BYTES].translate(None, allowed):
                    return None
            if f.read(1):
                return None
    except OSError:
        return None  # the usual path names the problem
    return data, start


def _data_start(head: bytearray, skip: int) -> int:
    """Where the line after the first ``skip`` lines starts in a file's first block (-1 if not
    in it, or after a CR or a byte order mark: those are left to the usual path)."""
    start = 0
    for _ in range(skip):
        end = head.find(b"\n", start)
        if end < 0:
            return -1
        start = end + 1
    if head.find(b"\r", 0, start) >= 0 or head.startswith(codecs.BOM_UTF8):
        return -1  # a CR ending moves the header's line count; a BOM: an unusual file
    return start


def _arrow_table(pa: Any, data: memoryview, sep: str, n_fields: int,
                 text: Collection[int]) -> Any:
    """pyarrow's table of the data rows: the text columns as strings, the others as float64,
    no cell read as missing (an empty cell is refused)."""
    from pyarrow import csv

    names = [f"c{i}" for i in range(n_fields)]
    types = {name: pa.string() if i in text else pa.float64() for i, name in enumerate(names)}
    return csv.read_csv(
        pa.py_buffer(data),
        read_options=csv.ReadOptions(column_names=names, use_threads=False),
        parse_options=csv.ParseOptions(delimiter=sep, quote_char=False, double_quote=False,
                                       escape_char=False, newlines_in_values=False,
                                       ignore_empty_lines=True),
        convert_options=csv.ConvertOptions(column_types=types, null_values=[],
                                           strings_can_be_null=False,
                                           quoted_strings_can_be_null=False),
        memory_pool=pa.system_memory_pool())


def _floats(column: Any) -> Array:
    """A float64 column without missing cells, copied out of pyarrow's buffers (its
    ``to_numpy`` imports pandas, ~64 MB)."""
    parts = [np.frombuffer(chunk.buffers()[1], dtype=np.float64, count=len(chunk),
                           offset=8 * chunk.offset) for chunk in column.chunks if len(chunk)]
    return np.concatenate(parts) if parts else np.zeros(0)


def _text(column: Any) -> tuple[NDArray[np.bytes_] | None, Text]:
    """A string column as numpy text, and as bytes when every cell has the same length (the
    usual time column: then no Python string is made per cell)."""
    parts = []
    width = -1
    for chunk in column.chunks:
        _, offsets_buf, data_buf = chunk.buffers()
        offsets = np.frombuffer(offsets_buf, dtype=np.int32)[chunk.offset:
                                                             chunk.offset + len(chunk) + 1]
        lengths = np.diff(offsets)
        if len(chunk) == 0 or lengths[0] == 0 or width not in (-1, lengths[0]) \
                or np.any(lengths != lengths[0]):
            return None, np.array(column.to_pylist(), dtype=str)
        width = int(lengths[0])
        parts.append(np.frombuffer(data_buf, dtype=f"S{width}", count=len(chunk),
                                   offset=int(offsets[0])))
    raw = np.concatenate(parts) if len(parts) > 1 else parts[0]
    return raw, raw.astype(f"U{width}")


def _text_numbers(cells: tuple[NDArray[np.bytes_] | None, Text]) -> Array | None:
    """A text column's numbers (None if a cell is no number: the usual path names it)."""
    raw, text = cells
    try:
        return (raw if raw is not None else text).astype(np.float64)
    except ValueError:
        return None
