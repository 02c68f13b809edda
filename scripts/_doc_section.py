"""Sections of docs/validation.md that the study and benchmark scripts rewrite.

A section is the text between ``<!-- BEGIN name -->`` and ``<!-- END name -->`` (each marker on
a line of its own). ``replace_section`` rewrites exactly that text and leaves every other byte
of the file as it was; it refuses (``SectionError``, one line) a file without the markers, with
either marker twice, or with the END before the BEGIN.

Every script that measures a table of the document takes the same two options
(``add_doc_options``): ``--write-doc`` rewrites its section(s) of ``--doc`` (default
docs/validation.md) with the markdown it prints.
"""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "validation.md"


class SectionError(Exception):
    """The document's markers do not delimit one section."""


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"


def _line_index(lines: list[str], marker: str, path: Path) -> int:
    hits = [k for k, line in enumerate(lines) if line.rstrip("\r\n").strip() == marker]
    if not hits:
        raise SectionError(f"{path}: no line '{marker}'; add the section's markers first")
    if len(hits) > 1:
        raise SectionError(f"{path}: '{marker}' appears {len(hits)} times (lines "
                           f"{', '.join(str(k + 1) for k in hits)}); keep one")
    return hits[0]


def section_text(text: str, name: str, path: Path = DOC) -> str:
    """The text between the markers of section ``name`` (without the marker lines)."""
    lines = text.splitlines(keepends=True)
    begin, end = (_line_index(lines, m, path) for m in _markers(name))
    if end < begin:
        raise SectionError(f"{path}: the END marker of '{name}' comes before its BEGIN")
    return "".join(lines[begin + 1:end])


def replace_in_text(text: str, name: str, body: str, path: Path = DOC) -> str:
    """``text`` with section ``name``'s body replaced by ``body`` (a final newline added)."""
    lines = text.splitlines(keepends=True)
    begin, end = (_line_index(lines, m, path) for m in _markers(name))
    if end < begin:
        raise SectionError(f"{path}: the END marker of '{name}' comes before its BEGIN")
    if body and not body.endswith("\n"):
        body += "\n"
    return "".join(lines[:begin + 1]) + body + "".join(lines[end:])


def replace_section(path: Path, name: str, body: str) -> None:
    """Rewrite section ``name`` of the file at ``path`` with ``body``."""
    path = Path(path)
    if not path.is_file():
        raise SectionError(f"{path}: no such file; pass --doc with the document to write")
    text = path.read_bytes().decode("utf-8")
    path.write_bytes(replace_in_text(text, name, body, path).encode("utf-8"))


def read_section(path: Path, name: str) -> str:
    """The current body of section ``name`` of the file at ``path``."""
    return section_text(Path(path).read_bytes().decode("utf-8"), name, Path(path))


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table (no trailing blank line)."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out) + "\n"


def number(x: float, digits: int = 2) -> str:
    """``x`` to ``digits`` significant figures: plain from 1e-3 to 1e4, else as ``3.7e-5``."""
    if x == 0 or 1e-3 <= abs(x) < 1e4:
        return f"{x:.{digits}g}"
    return f"{x:.{digits - 1}e}".replace("e-0", "e-").replace("e+0", "e+")


def upsert_row(body: str, cells: list[str]) -> str:
    """``body`` (a section holding one markdown table) with the row whose first cell is
    ``cells[0]`` replaced by ``cells``, or appended after the table's last row."""
    lines = body.splitlines(keepends=True)
    rows = [k for k, line in enumerate(lines) if line.startswith("|")]
    if len(rows) < 2:
        raise SectionError("the section holds no table to put the row in")
    new = "| " + " | ".join(cells) + " |\n"
    for k in rows[2:]:
        if lines[k].split("|")[1].strip() == cells[0].strip():
            lines[k] = new
            return "".join(lines)
    lines.insert(rows[-1] + 1, new)
    return "".join(lines)


def command_line(script: str) -> str:
    """How this run was started (without the doc options), for the section's provenance."""
    args, skip = [], False
    for a in sys.argv[1:]:
        if skip:
            skip = False
            continue
        if a == "--write-doc" or a.startswith("--doc="):
            continue
        if a == "--doc":
            skip = True
            continue
        # The recordings' folder as the project names it, not this machine's path to it.
        args.append(re.sub(r"^\S*/shared/data/", "../shared/data/", a))
    return " ".join(["python", f"scripts/{script}", *map(shlex.quote, args)])


def commit() -> str:
    """The short commit of the working tree ('+' when it has local changes), or ''."""
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--",
                                "mocap_calib", "scripts"], capture_output=True, text=True,
                               check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""
    return head + ("+" if dirty else "")


def provenance(script: str) -> str:
    """One line naming the command and the commit that produced a section."""
    c = commit()
    return f"Measured with `{command_line(script)}`" + (f" (commit {c})." if c else ".") + "\n"


def add_doc_options(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--write-doc", action="store_true",
                    help="also rewrite this script's section(s) of --doc with the table")
    ap.add_argument("--doc", type=Path, default=DOC,
                    help=f"the document to rewrite (default {DOC.relative_to(ROOT)})")


def check(args: argparse.Namespace, names: list[str]) -> None:
    """With ``--write-doc``: before measuring, exit 2 with one line unless ``args.doc`` holds
    each named section once (a long run is not spent on a document it cannot write)."""
    if not args.write_doc:
        return
    try:
        text = Path(args.doc).read_bytes().decode("utf-8")
        for name in names:
            section_text(text, name, Path(args.doc))
    except (OSError, SectionError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)


def write(args: argparse.Namespace, sections: dict[str, str]) -> None:
    """With ``--write-doc``: rewrite each named section of ``args.doc``; exit 2 with one line
    when the document lacks a section's markers (no section is written then)."""
    if not args.write_doc:
        return
    if not sections:
        print(f"nothing written to {args.doc}: this run measured none of its sections in full")
        return
    try:
        text = Path(args.doc).read_bytes().decode("utf-8")
        for name, body in sections.items():
            text = replace_in_text(text, name, body, Path(args.doc))
    except (OSError, SectionError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    Path(args.doc).write_bytes(text.encode("utf-8"))
    print(f"wrote section(s) {', '.join(sections)} of {args.doc}")
