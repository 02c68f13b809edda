"""Layout sniffing and table reading of delimited text files (shared by the generic, EuRoC,
TUM and imu_tk readers): delimiter, header, first data row, decimal mark; numeric columns
parsed with one-line errors naming the line."""

from __future__ import annotations

import re
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import input_error
from mocap_calib.io.checks import Lines
from mocap_calib.io.formats.columns import COLUMNS_FIX
from mocap_calib.io.pandas_csv import pd

Array = NDArray[np.float64]

#: pandas separator for whitespace-delimited files.
WHITESPACE = r"\s+"
_HEAD_LINES = 200


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
                              f"{layout.n_fields} columns)", COLUMNS_FIX, layout.source,
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
                          f"{frame.shape[1]} columns)", COLUMNS_FIX, layout.source,
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
