"""The numpy table reader against pandas' (the parser it replaced) and exact decimal stamps
against Python's decimal arithmetic."""

from __future__ import annotations

from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mocap_calib.errors import InputError
from mocap_calib.io.formats.layout import WHITESPACE, read_table, sniff_layout
from mocap_calib.io.formats.stamps import parse_stamps
from mocap_calib.io.validate import Lines

FILES = {
    "clean.csv": "#t,a,b\n1,0.5,2e-3\n2,-1.25,3\n3,7,1e300\n",
    "comments_blank_crlf.csv": "t,a,b\r\n1,0.1,0.2 # note\r\n\r\n# whole line\r\n2,0.3,0.4\r\n",
    "empty_na_short.csv": "t,a,b\n1,,0.2\n2,NA,nan\n3,0.5\n4, 1.5 ,  -inf\n",
    "spaces.txt": "# t a b\n1\t0.1   0.2\n  2 0.3\t0.4  \n\n3 5 6\n",
    "semicolon_comma.csv": "t;a;b\n1,5;0,25;3\n2,5;-1,5;4,75\n",
}


def _pandas(path: Path, layout) -> pd.DataFrame:
    kw = {"sep": layout.sep, "header": None, "skiprows": layout.skip, "comment": "#",
          "decimal": layout.decimal}
    if layout.sep != WHITESPACE:
        kw["skipinitialspace"] = True
    return pd.read_csv(path, **kw)


@pytest.mark.parametrize("name", sorted(FILES))
def test_numbers_match_pandas(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(FILES[name].encode())
    layout = sniff_layout(path)
    table = read_table(layout, [0, 1, 2], 0)
    ref = _pandas(path, layout)
    assert not table.bad
    for c in (1, 2):
        np.testing.assert_array_equal(table.numbers[c], ref[c].to_numpy(dtype=float))
    assert len(table.text[0]) == len(ref)


def test_words_and_long_rows_are_named_at_their_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("t,a,b\n1,0.1,0.2\n\n# c\n2,x1,0.3\n3,0.1,y\n")
    layout = sniff_layout(path)
    table = read_table(layout, [0, 1, 2], 0)
    assert table.bad == {1: (1, "x1"), 2: (2, "y")}
    assert Lines(str(path), path, layout.skip).line(1) == 5
    path.write_text("t,a,b\n1,0.1,0.2\n2,0.1,0.3,9\n")
    with pytest.raises(InputError, match="line 3.*same columns"):
        read_table(sniff_layout(path), [0, 1], 0)


def _decimal_ns(text: str, scale: int) -> int:
    return int((Decimal(text) * scale).to_integral_value(rounding=ROUND_HALF_UP))


@pytest.mark.parametrize(("cells", "unit", "scale"), [
    (["1413394881.394290944", "1413394881.394290945", "1413394881.5"], "s", 10**9),
    (["0.0035", "+12.25", "-3.5", ".5", "7."], "s", 10**9),
    (["1.0000000004", "1.0000000005", "2.00000000049"], "s", 10**9),  # rounding below 1 ns
    (["1600000000000000000", "1600000000005000000"], "ns", 1),
    (["1.25", "2.5", "3"], "ms", 10**6),
])
def test_decimal_stamps_are_exact(cells: list[str], unit: str, scale: int) -> None:
    got = parse_stamps(np.array(cells), unit, "t", Lines("x"))
    assert got.tolist() == [_decimal_ns(c, scale) for c in cells]


def test_exponent_stamps_go_through_floats_and_bad_ones_are_refused() -> None:
    assert parse_stamps(np.array(["1.5e3", "2e3"]), "s", "t", Lines("x")).tolist() == \
        [1_500_000_000_000, 2_000_000_000_000]
    for cells, what in ((["1", ""], "empty or NaN"), (["1", "NA"], "empty or NaN"),
                        (["1", "12x4"], "'12x4', not a number"),
                        (["1.5", "2.5"], "whole numbers"),
                        (["99999999999999999999"], "overflow")):
        with pytest.raises(InputError, match=what):
            parse_stamps(np.array(cells), "ns", "t", Lines("x"))


def test_quoted_fields_are_read_like_pandas(tmp_path: Path) -> None:
    """Some exporters quote every field: the numbers are read, not refused as a header."""
    path = tmp_path / "quoted.csv"
    path.write_text('"t","a","b"\n"1.5","0.25","-3"\n"2.5","","1e-3"\n')
    layout = sniff_layout(path)
    table = read_table(layout, [0, 1, 2], 0)
    ref = _pandas(path, layout)
    for c in (1, 2):
        np.testing.assert_array_equal(table.numbers[c], ref[c].to_numpy(dtype=float))
    assert parse_stamps(table.text[0], "s", "t", Lines("x")).tolist() == [1_500_000_000,
                                                                         2_500_000_000]


@pytest.mark.parametrize(("cells", "unit", "scale"), [
    (["1413394881575760384", "9223372036854775807", "0000000000000000001"], "ns", 1),
    (["9223372036", "1000000000", "0000000009"], "ns", 1),
    (["12", "13", "99"], "ms", 10**6),
    (["1", "12", "123"], "us", 10**3),  # cells of several widths: the general path
    (["١٢", "١٣"], "ms", 10**6),  # other decimal digits: the general path
])
def test_whole_number_stamps_are_exact(cells: list[str], unit: str, scale: int) -> None:
    got = parse_stamps(np.array(cells), unit, "t", Lines("x"))
    assert got.tolist() == [int(Decimal(c)) * scale for c in cells]


@pytest.mark.parametrize("cell", ["9223372036854775808", "9999999999999999999"])
def test_nineteen_digits_beyond_int64_are_refused(cell: str) -> None:
    with pytest.raises(InputError, match="overflow"):
        parse_stamps(np.array(["1000000000000000000", cell]), "ns", "t", Lines("x"))
