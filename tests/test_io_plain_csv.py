"""Large plain CSV files through pyarrow's parser: the same table as the numpy path, bit for
bit; every other file falls back to the numpy path, with the same table or the same message."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from mocap_calib.errors import InputError
from mocap_calib.io import tables
from mocap_calib.io.formats.euroc import read_euroc_imu, write_euroc_imu
from mocap_calib.io.formats.layout import WHITESPACE, Layout, read_table, sniff_layout
from mocap_calib.sim.flight import SimConfig, simulate_flight

NEVER = 1 << 62  # PYARROW_MIN_BYTES that keeps every file on the numpy path

#: Cells that test the rounding and the grammar of both parsers.
TRICKY = ["1e-300", "0.1", "0.30000000000000004", "-0", "-0.0", "+1.5", ".5", "-.5", "5.",
          "5.e3", "1E5", "1e+05", "00012", "1.7976931348623157e308", "1e309", "-1e309",
          "1e-400", "4.9e-324", "2.4703282292062327e-324", "2.4703282292062328e-324",
          "9007199254740993", "123456789012345678901234567890", "0.1000000000000000055511151231"
          "257827021181583404541015625", "2.2250738585072011e-308", "1600000000005000001"]


def _snapshot(layout: Layout, indices: list[int], time_index: int) -> object:
    """read_table's table as plain data (numbers by their bits), or its error message."""
    try:
        t = read_table(layout, indices, time_index)
    except InputError as err:
        return ("error", str(err))
    for v in t.numbers.values():
        assert v.dtype == np.float64 and v.flags.c_contiguous and v.flags.writeable
    return ({c: v.view(np.int64).tolist() for c, v in t.numbers.items()}, t.bad,
            {c: (str(v.dtype), v.tolist()) for c, v in t.text.items()})


def _both_ways(path: Path, monkeypatch: pytest.MonkeyPatch, indices: list[int] | None = None,
               time_index: int = 0) -> tuple[object, object, bool]:
    """(numpy path, pyarrow path when the file is plain, whether that one read it)."""
    layout = sniff_layout(path)
    indices = list(range(layout.n_fields)) if indices is None else indices
    monkeypatch.setattr(tables, "PYARROW_MIN_BYTES", NEVER)
    slow = _snapshot(layout, indices, time_index)
    monkeypatch.setattr(tables, "PYARROW_MIN_BYTES", 0)
    fast = _snapshot(layout, indices, time_index)
    sep = None if layout.sep == WHITESPACE else layout.sep
    taken = tables.read_plain(path, layout.skip, sep, layout.decimal, layout.n_fields,
                                 indices, [time_index]) is not None
    return slow, fast, taken


def _numbers_file(path: Path, rows: int, seed: int, sep: str = ",", header: bool = True) -> Path:
    """Random doubles of every magnitude (shortest repr, 17 digits, exponents), the tricky
    cells, integer stamps; more than one of pyarrow's 1 MB blocks when ``rows`` is large."""
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 2**63, (rows, 4), dtype=np.int64)
    x = bits.view(np.float64)
    x[~np.isfinite(x)] = 0.0
    x[:, 1] = rng.normal(size=rows)
    x[rng.random(rows) < 0.5, 0] *= -1
    cells = [[repr(float(v)) for v in row] for row in x.tolist()]
    for r in range(0, rows, max(1, rows // 200)):
        cells[r][2] = f"{x[r, 2]:.17e}"
        cells[r][3] = TRICKY[r % len(TRICKY)]
    stamps = 1_600_000_000_000_000_000 + 5_000_000 * np.arange(rows)
    lines = [sep.join([str(t), *row]) for t, row in zip(stamps.tolist(), cells, strict=True)]
    path.write_text(("#t [ns],a,b,c,d\n" if header else "") + "\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("rows", [3, 40_000])
@pytest.mark.parametrize("sep", [",", ";"])
def test_plain_files_read_the_same_both_ways(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             rows: int, sep: str) -> None:
    path = _numbers_file(tmp_path / "numbers.csv", rows, seed=rows, sep=sep)
    slow, fast, taken = _both_ways(path, monkeypatch)
    assert taken and fast == slow


def test_edge_layouts_read_the_same_both_ways(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """No header, no last newline, blank lines, decimal-second stamps of varying length, a
    column asked for twice, the time column not first."""
    base = _numbers_file(tmp_path / "base.csv", 2000, seed=3, header=False).read_text()
    rows = base.splitlines()
    cases = {
        "no_header": base,
        "no_last_newline": base.rstrip("\n"),
        "blank_lines": "#t,a,b,c,d\n\n" + "\n\n".join(rows[:50]) + "\n\n\n" + "\n".join(rows[50:]),
        "decimal_seconds": "t,a,b,c,d\n" + "\n".join(
            f"{0.0035 * k:.6g},{r.split(',', 1)[1]}" for k, r in enumerate(rows)) + "\n",
    }
    for name, text in cases.items():
        path = tmp_path / f"{name}.csv"
        path.write_text(text)
        slow, fast, taken = _both_ways(path, monkeypatch)
        assert taken and fast == slow, name
    path = tmp_path / "no_header.csv"
    for indices, time_index in (([2, 0, 2, 4], 0), ([0, 1, 3], 3), ([1, 2], 4)):
        slow, fast, taken = _both_ways(path, monkeypatch, indices, time_index)
        assert taken and fast == slow, (indices, time_index)


def test_cells_pyarrow_accepts_are_numpys_bits(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """Any cell of the plain alphabet, as a stamp and as a value: pyarrow's table is the numpy
    path's whenever pyarrow reads it (and it falls back when not)."""
    rng = random.Random(5)
    cells = TRICKY + ["".join(rng.choice("0123456789.+-eE") for _ in range(rng.randint(1, 9)))
                      for _ in range(400)]
    path = tmp_path / "cell.csv"
    taken = 0
    for cell in cells:
        path.write_text(f"t,a\n1,2\n{cell},{cell}\n")
        slow, fast, ok = _both_ways(path, monkeypatch)
        assert fast == slow, cell
        taken += ok
    assert taken > len(TRICKY)


#: Files the pyarrow path leaves to the numpy path: (name, text). Row 3 onwards repeats.
FALLBACKS = {
    "comment_line": "t,a,b\n1,0.5,2\n# note\n2,0.25,3\n",
    "trailing_comment": "t,a,b\n1,0.5,2 # note\n2,0.25,3\n",
    "decimal_comma": "t;a;b\n1,5;0,25;3\n2,5;-1,5;4,75\n",
    "quotes": '"t","a","b"\n"1","0.5","2"\n"2","0.25","3"\n',
    "longer_row": "t,a,b\n1,0.5,2\n2,0.25,3,9\n",
    "shorter_row": "t,a,b\n1,0.5,2\n2,0.25\n",
    "na_cell": "t,a,b\n1,0.5,2\n2,NA,3\n",
    "nan_cell": "t,a,b\n1,0.5,2\n2,nan,3\n",
    "inf_cell": "t,a,b\n1,0.5,2\n2,inf,3\n",
    "empty_cell": "t,a,b\n1,0.5,2\n2,,3\n",
    "empty_stamp": "t,a,b\n1,0.5,2\n,0.25,3\n",
    "empty_row": "t,a,b\n1,0.5,2\n,,\n",
    "word_cell": "t,a,b\n1,0.5,2\n2,x1,3\n",
    "not_a_number": "t,a,b\n1,0.5,2\n2,1e,3\n",
    "underscore": "t,a,b\n1,0.5,2\n2,1_000,3\n",
    "bom_no_header": "\ufeff1,0.5,2\n2,0.25,3\n",
    "bom_header": "\ufefft,a,b\n1,0.5,2\n2,0.25,3\n",
    "crlf": "t,a,b\r\n1,0.5,2\r\n2,0.25,3\r\n",
    "cr_in_header": "t,a,b\r\n1,0.5,2\n2,0.25,3\n",
    "cr_only": "t,a,b\r1,0.5,2\r2,0.25,3\r",
    "spaces": "t, a, b\n1, 0.5, 2\n2, 0.25, 3\n",
    "tab_in_cell": "t,a,b\n1,0.5,2\n2,\t0.25,3\n",
    "whitespace_separated": "# t a b\n1 0.5 2\n2\t0.25  3\n",
    "other_separator_in_row": "t,a,b\n1,0.5,2\n2;0.25;3\n",
    "non_utf8": "t,a,b\n1,0.5,2\n2,0.25,3\xff\n",
}


@pytest.mark.parametrize("name", sorted(FALLBACKS))
def test_unusual_files_fall_back_with_the_same_table_or_message(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    text = FALLBACKS[name]
    head, _, rest = text.partition("\n")
    first, sep, more = rest.partition("\n")
    body = first + sep + (more * 3000 if more else "")  # large enough for more than one block
    path = tmp_path / f"{name}.csv"
    path.write_bytes((head + "\n" + body).encode("utf-8", errors="surrogateescape")
                     .replace(b"\xc3\xbf", b"\xff"))
    slow, fast, taken = _both_ways(path, monkeypatch)
    assert not taken and fast == slow


def test_messages_after_reading_name_the_same_line(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A problem found in the table (a stamp going back) names the same line both ways."""
    imu = simulate_flight(SimConfig(duration=30.0)).imu
    path = write_euroc_imu(tmp_path / "imu.csv", imu)
    lines = path.read_text().splitlines()
    lines[4000], lines[4001] = lines[4001], lines[4000]
    path.write_text("\n".join(lines) + "\n")
    messages = []
    for min_bytes in (NEVER, 0):
        monkeypatch.setattr(tables, "PYARROW_MIN_BYTES", min_bytes)
        with pytest.raises(InputError) as err:
            read_euroc_imu(path)
        messages.append(str(err.value))
    assert messages[0] == messages[1] and "line 4002" in messages[0]


def test_small_files_stay_on_the_numpy_path(tmp_path: Path) -> None:
    path = _numbers_file(tmp_path / "small.csv", 100, seed=1)
    layout = sniff_layout(path)
    assert path.stat().st_size < tables.PYARROW_MIN_BYTES
    assert tables.read_plain(path, layout.skip, ",", ".", layout.n_fields, [1], [0]) is None


def test_a_late_unusual_cell_falls_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The check goes block by block: a NaN in the last row of a file of several blocks."""
    path = _numbers_file(tmp_path / "late.csv", 40_000, seed=2)
    with open(path, "a") as f:
        f.write("1600000200000000000,nan,0.5,0.25,1\n")
    slow, fast, taken = _both_ways(path, monkeypatch)
    assert path.stat().st_size > 3 * 2**20 and not taken and fast == slow
