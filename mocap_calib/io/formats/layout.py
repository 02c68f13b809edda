"""Layout sniffing and table reading of delimited text files (shared by the generic, EuRoC,
TUM, imu_tk and mocap-export readers): delimiter, header, first data row, decimal mark; numeric
columns parsed with one-line errors naming the line.

The rows are parsed with numpy, not pandas: importing pandas costs ~64 MB of resident memory, a
fifth of a short session's whole run. Clean files go through numpy's C parser; a file it refuses
(an empty cell, ``NA``, a word in a column, a short row) is read again row by row, so that each
problem is named at its line. The rules: a ``#`` starts a comment, blank lines are skipped, a row
with more fields than the first data row is an error, missing trailing fields and empty or
``NA``-like cells are NaN.

Large files of numbers only (from 8 MiB: tens of MB of IMU readings) are read by pyarrow's parser
instead (:func:`mocap_calib.io.tables.read_plain`), into the same table several times faster; a
file that is not plain, or that it refuses, is read as above."""

from __future__ import annotations

import warnings
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import input_error
from mocap_calib.io.formats.columns import COLUMNS_FIX, name_key
from mocap_calib.io.tables import read_plain
from mocap_calib.io.validate import Lines

__all__ = ["name_key"]  # re-exported: header names are matched by it

Array = NDArray[np.float64]

#: The separator of whitespace-delimited files (runs of spaces or tabs).
WHITESPACE = r"\s+"
_HEAD_LINES = 200


@dataclass(frozen=True)
class Layout:
    """How a delimited text file is laid out (found from its first lines).

    Attributes:
        path: The file.
        sep: The separator: ``","``, ``";"`` or :data:`WHITESPACE`.
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


def _detect_sep(line: str) -> str:
    if ";" in line:
        return ";"
    if "," in line:
        return ","
    return WHITESPACE


def _split(line: str, sep: str) -> list[str]:
    """Fields, stripped of spaces and of the double quotes some exporters put around every
    field."""
    if sep == WHITESPACE:
        return [t.strip('"') for t in line.split()]
    return [t.strip().strip('"') for t in line.split(sep)]


def _header_names(line: str, sep: str, n_fields: int) -> tuple[str, ...]:
    """The header's names; a tab-separated header over whitespace-separated data keeps the
    names that contain spaces (``timestamp [ns]``) whole."""
    text = line.lstrip("#").strip()
    if sep == WHITESPACE and "\t" in text:
        tabbed = tuple(t.strip() for t in text.split("\t") if t.strip())
        if len(tabbed) == n_fields:
            return tabbed
    return tuple(t.strip() for t in _split(text, sep))


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
                    names = _header_names(prev[1], sep, len(tokens))
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


#: Cells read as NaN (missing values as spreadsheets and loggers write them).
NA_CELLS = frozenset({"", "nan", "NaN", "-nan", "-NaN", "NA", "N/A", "n/a", "#N/A", "NULL",
                      "null", "None", "<NA>"})


class RaggedRow(Exception):
    """A data row with more fields than the first one (``row`` is its 0-based data row)."""

    def __init__(self, row: int) -> None:
        super().__init__(row)
        self.row = row


@dataclass(frozen=True)
class Table:
    """Some columns of a file's data rows.

    Attributes:
        numbers: 0-based column -> (N,) float64, NaN where a cell is empty, NA or no number.
        bad: 0-based column -> (first data row, its text) of a cell that is no number.
        text: 0-based column -> (N,) its cells as text, unstripped (the columns asked for as
            text).
    """

    numbers: dict[int, Array]
    bad: dict[int, tuple[int, str]]
    text: dict[int, NDArray[np.str_]]


def data_lines(path: Path, skip: int, decimal: str = ".") -> list[str]:
    """The data lines of a file: after ``skip`` raw lines, comments cut, blank lines dropped
    (the row numbering of :class:`~mocap_calib.io.validate.Lines`); a ``,`` decimal mark
    becomes ``.`` (the delimiter is then ``;``).

    Raises:
        InputError: the file cannot be read.
    """
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as f:
            text = f.read()
    except OSError as err:
        raise input_error(f"cannot read the file ({err.strerror})",
                          "check the path and its permissions", str(path)) from None
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")[skip:]
    if any("#" in line for line in lines):
        lines = [line.partition("#")[0] for line in lines]
    lines = [line for line in lines if line and not line.isspace()]
    if decimal != ".":
        lines = [line.replace(decimal, ".") for line in lines]
    return lines


def parse_rows(lines: list[str], sep: str | None, n_fields: int, numeric: Collection[int],
               text: Collection[int] = (), ragged_ok: bool = False) -> Table:
    """Parse data lines into a :class:`Table`.

    Args:
        lines: The data lines (:func:`data_lines`).
        sep: The delimiter, or None for runs of whitespace.
        n_fields: Fields of the first data row; a longer row raises :class:`RaggedRow` unless
            ``ragged_ok``.
        numeric: Columns wanted as numbers.
        text: Columns wanted as text.
        ragged_ok: Rows may be longer than the first (extra fields are ignored).

    Raises:
        RaggedRow: a row has more fields than ``n_fields``.
    """
    numeric = sorted(set(numeric))
    values = None
    if not ragged_ok:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data"
                values = np.loadtxt(lines, delimiter=sep, dtype=np.float64, comments=None,
                                    ndmin=2, quotechar='"')
        except ValueError:
            values = None
        if values is not None and len(lines) and values.shape[1] != n_fields:
            values = None
    if values is not None:
        numbers = {c: np.ascontiguousarray(values[:, c]) if len(lines) else np.zeros(0)
                   for c in numeric}
        bad: dict[int, tuple[int, str]] = {}
    else:
        numbers, bad = _parse_slowly(lines, sep, n_fields, numeric, ragged_ok)
    cells = {c: np.array(_cells(lines, sep, c), dtype=str) for c in text}
    return Table(numbers, bad, cells)


def _cells(lines: list[str], sep: str | None, i: int) -> list[str]:
    """Field ``i`` of every line, unstripped ("" where a row is shorter)."""
    if i == 0:  # the usual time column: 3x faster than splitting every field
        if sep is None:
            return [line.split(None, 1)[0] for line in lines]
        return [line.partition(sep)[0] for line in lines]
    return [parts[i] if len(parts := line.split(sep, i + 1)) > i else "" for line in lines]


def _parse_slowly(lines: list[str], sep: str | None, n_fields: int, numeric: list[int],
                  ragged_ok: bool) -> tuple[dict[int, Array], dict[int, tuple[int, str]]]:
    """Row by row: NaN for missing and NA cells, the first non-number of each column kept."""
    out = {c: np.full(len(lines), np.nan) for c in numeric}
    bad: dict[int, tuple[int, str]] = {}
    for r, line in enumerate(lines):
        fields = line.split(sep)
        if len(fields) > n_fields and not ragged_ok:
            raise RaggedRow(r)
        for c in numeric:
            if c >= len(fields):
                continue
            cell = fields[c].strip().strip('"')
            if cell in NA_CELLS:
                continue
            try:
                if "_" in cell:  # Python's float() reads 1_000; no CSV writer means that
                    raise ValueError(cell)
                out[c][r] = float(cell)
            except ValueError:
                bad.setdefault(c, (r, cell))
    return out, bad


def read_table(layout: Layout, indices: Collection[int], time_index: int) -> Table:
    """Read the given columns (the time column as text, for exact stamps).

    Args:
        layout: The file's layout.
        indices: 0-based columns to read.
        time_index: The time column (kept as text).

    Returns:
        The columns, by their 0-based index.
    """
    for i in indices:
        if i >= layout.n_fields:
            raise input_error(f"column {i} does not exist (the first data row has "
                              f"{layout.n_fields} columns)", COLUMNS_FIX, layout.source,
                              layout.skip + 1)
    sep = None if layout.sep == WHITESPACE else layout.sep
    plain = read_plain(layout.path, layout.skip, sep, layout.decimal, layout.n_fields, indices,
                       [time_index])
    if plain is not None:  # a large file of numbers only: the same table, faster
        return Table(plain[0], {}, plain[1])
    lines = data_lines(layout.path, layout.skip, layout.decimal)
    try:
        # All columns are parsed (not only those asked for) so that a longer row is an error.
        return parse_rows(lines, sep, layout.n_fields, indices, text=[time_index])
    except RaggedRow as err:
        raise layout.lines().error("row does not split into the same columns as the first "
                                   "data row", "check the delimiter and that every row has "
                                   "the same columns", err.row) from None


def numeric_column(table: Table, index: int, layout: Layout, lines: Lines) -> Array:
    """Column ``index`` as float64, raising at the first value that is no number.

    Empty fields and ``nan`` become NaN (the stream checks decide whether that is allowed).
    """
    if index in table.bad:
        row, cell = table.bad[index]
        raise lines.error(f"column {layout.label(index)} holds {cell!r}, not a number",
                          "fix or delete that line", row)
    return table.numbers[index]
