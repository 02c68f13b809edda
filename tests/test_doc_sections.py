"""The sections of docs/validation.md that the study and benchmark scripts rewrite
(scripts/_doc_section.py): exactly the named block is replaced, every other byte stays, and a
document without the markers (or with one twice, or out of order) is refused untouched. Every
section a script declares is in the document once."""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import _doc_section as ds  # noqa: E402

DOC = ("# Title\r\n"  # mixed line endings, trailing spaces, no final newline: kept as they are
       "Intro text with trailing spaces   \n"
       "<!-- BEGIN alpha -->\n"
       "| a | b |\n|---|---|\n| 1 | 2 |\n"
       "<!-- END alpha -->\n"
       "between\t(tab) and unicode: ± σ\n"
       "<!-- BEGIN beta -->\n"
       "old beta\n"
       "<!-- END beta -->\n"
       "tail without newline")


def test_replaces_only_the_named_section() -> None:
    out = ds.replace_in_text(DOC, "beta", "new beta line 1\nline 2")
    assert ds.section_text(out, "beta") == "new beta line 1\nline 2\n"
    assert ds.section_text(out, "alpha") == ds.section_text(DOC, "alpha")
    # Everything outside beta's body is byte-identical, in order.
    head, _, rest = DOC.partition("<!-- BEGIN beta -->\n")
    tail = rest[rest.index("<!-- END beta -->"):]
    assert out == head + "<!-- BEGIN beta -->\n" + "new beta line 1\nline 2\n" + tail
    assert out.startswith("# Title\r\n") and out.endswith("tail without newline")


def test_replace_then_restore_is_identity() -> None:
    old = ds.section_text(DOC, "alpha")
    assert ds.replace_in_text(ds.replace_in_text(DOC, "alpha", "x\n"), "alpha", old) == DOC


def test_an_empty_body_leaves_the_markers_adjacent() -> None:
    out = ds.replace_in_text(DOC, "alpha", "")
    assert "<!-- BEGIN alpha -->\n<!-- END alpha -->\n" in out


@pytest.mark.parametrize("broken, words", [
    (DOC.replace("<!-- BEGIN beta -->\n", ""), "no line '<!-- BEGIN beta -->'"),
    (DOC.replace("<!-- END beta -->\n", ""), "no line '<!-- END beta -->'"),
    (DOC.replace("old beta\n", "old beta\n<!-- BEGIN beta -->\n"), "appears 2 times"),
    (DOC + "\n<!-- END beta -->\n", "appears 2 times"),
    (DOC.replace("<!-- BEGIN beta -->\nold beta\n<!-- END beta -->",
                 "<!-- END beta -->\nold beta\n<!-- BEGIN beta -->"), "comes before its BEGIN"),
])
def test_refuses_missing_duplicated_or_swapped_markers(broken: str, words: str) -> None:
    with pytest.raises(ds.SectionError, match="doc.md: .*" + words.replace("(", r"\(")
                       .replace(")", r"\)").replace("*", r"\*")):
        ds.replace_in_text(broken, "beta", "new\n", Path("doc.md"))


def test_a_marker_inside_a_line_is_not_a_marker() -> None:
    text = "see `<!-- BEGIN beta -->` here\n<!-- BEGIN beta -->\nx\n<!-- END beta -->\n"
    assert ds.section_text(text, "beta") == "x\n"


def test_file_is_untouched_when_refused(tmp_path: Path) -> None:
    path = tmp_path / "v.md"
    broken = DOC.replace("<!-- END alpha -->\n", "")
    path.write_bytes(broken.encode())
    with pytest.raises(ds.SectionError):
        ds.replace_section(path, "alpha", "new\n")
    assert path.read_bytes() == broken.encode()


def test_write_rewrites_every_section_or_none(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "v.md"
    path.write_bytes(DOC.encode())
    args = argparse.Namespace(write_doc=True, doc=path)
    with pytest.raises(SystemExit) as ex:  # gamma is missing: alpha is not written either
        ds.write(args, {"alpha": "changed\n", "gamma": "x\n"})
    assert ex.value.code == 2
    assert "error: " in capsys.readouterr().err
    assert path.read_bytes().decode() == DOC
    with pytest.raises(SystemExit):
        ds.check(args, ["alpha", "gamma"])
    ds.check(args, ["alpha", "beta"])
    ds.write(args, {"alpha": "changed\n", "beta": "b\n"})
    out = path.read_bytes().decode()
    assert ds.section_text(out, "alpha") == "changed\n" and ds.section_text(out, "beta") == "b\n"
    ds.write(argparse.Namespace(write_doc=False, doc=path), {"alpha": "ignored\n"})
    assert path.read_bytes().decode() == out


def test_upsert_row_replaces_by_first_cell_or_appends() -> None:
    body = "Intro.\n\n" + ds.table(["session", "wall"], [["A", "1 s"], ["B", "2 s"]]) + "\nEnd.\n"
    out = ds.upsert_row(body, ["B", "3 s"])
    assert "| B | 3 s |" in out and "| B | 2 s |" not in out and out.endswith("\nEnd.\n")
    out = ds.upsert_row(out, ["C", "4 s"])
    assert out.index("| C | 4 s |") > out.index("| B | 3 s |") and out.endswith("\nEnd.\n")
    with pytest.raises(ds.SectionError):
        ds.upsert_row("no table\n", ["A", "1 s"])


def _declared_sections() -> dict[str, tuple[str, ...]]:
    """SECTIONS of every script that writes the document (read from the source)."""
    out = {}
    for path in sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if (isinstance(node, ast.Assign) and len(node.targets) == 1
                    and getattr(node.targets[0], "id", None) == "SECTIONS"):
                out[path.name] = tuple(ast.literal_eval(node.value))
    return out


def test_every_declared_section_is_in_the_document_once() -> None:
    declared = _declared_sections()
    assert len(declared) >= 11, sorted(declared)
    text = (ROOT / "docs" / "validation.md").read_text(encoding="utf-8")
    names = [n for sections in declared.values() for n in sections]
    assert len(names) == len(set(names)), "two scripts write the same section"
    for script, sections in declared.items():
        for name in sections:
            ds.section_text(text, name)  # raises unless the markers are there once, in order
        src = (ROOT / "scripts" / script).read_text()
        assert "add_doc_options(" in src and "write(" in src, script
    begins = {line.split()[2] for line in text.splitlines() if line.startswith("<!-- BEGIN ")}
    assert begins == set(names), f"sections no script writes: {sorted(begins - set(names))}"
