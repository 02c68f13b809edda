"""One self-contained HTML page: sections of tables, figures and notes, and how it was made.

Everything is inline (CSS, images as ``data:`` URIs), so the file opens offline and makes no
network request. Numbers that come from a result file carry ``data-key`` (the key path in the
YAML, ``/`` between keys and list indices, as in a JSON pointer) and ``data-value`` (the value
at full precision), so a reader, or a test, can check the page against the file.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

__all__ = ["Cell", "Table", "Figure", "Notes", "Row", "Section", "InputFile", "Provenance",
           "render_html"]


@dataclass(frozen=True)
class Cell:
    """A table cell: its text and, for a number read from the result file, where it is there.

    Attributes:
        text: what the page shows (already formatted, in ``scale`` times the file's unit).
        key: key path in the result file, e.g. ``sigma.gyro_bias.0`` (None: no file value).
        value: the file's value at full precision.
        scale: shown number = ``value * scale`` (unit conversion, e.g. 1000 for m -> mm).
    """

    text: str
    key: str | None = None
    value: float | str | None = None
    scale: float = 1.0


@dataclass
class Table:
    """A table; cells are strings or :class:`Cell`."""

    id: str
    header: Sequence[str]
    rows: Sequence[Sequence[str | Cell]]
    caption: str = ""


@dataclass
class Figure:
    """An image with its caption.

    Attributes:
        id: element id (``fig-...``).
        caption: what the figure shows, with its key numbers.
        png: the image (PNG bytes), or ``svg``: an SVG document.
        data: extra ``data-*`` attributes (key numbers, machine-readable).
    """

    id: str
    caption: str
    png: bytes | None = None
    svg: str | None = None
    data: dict[str, str] = field(default_factory=dict)


@dataclass
class Notes:
    """A list of one-line notes (warnings, verdict reasons); ``kind`` styles it."""

    id: str
    lines: Sequence[str]
    kind: str = "note"  # note | warning | ok


@dataclass
class Row:
    """Blocks side by side (wrapping on narrow screens)."""

    blocks: list[Table | Figure | Notes | str]


@dataclass
class Section:
    id: str
    title: str
    blocks: list[Table | Figure | Notes | Row | str] = field(default_factory=list)
    intro: str = ""


@dataclass(frozen=True)
class InputFile:
    path: str
    size_bytes: int
    sha256: str


@dataclass
class Provenance:
    """How a result was made (gathered by the workflow that wrote it).

    Attributes:
        tool: name and version, e.g. ``mocap-calib 0.1.0``.
        command: the command line.
        inputs: the files read, with sizes and hashes.
        started: local start time (ISO 8601).
        seconds: run time of the command up to the report.
        extra: further (label, value) lines, e.g. Python and library versions.
    """

    tool: str
    command: str
    inputs: list[InputFile] = field(default_factory=list)
    started: str = ""
    seconds: float = 0.0
    extra: list[tuple[str, str]] = field(default_factory=list)


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Helvetica,Arial,sans-serif;margin:0;
 color:#1d1d1f;background:#fafafa;line-height:1.4}
main{max-width:1240px;margin:0 auto;padding:16px 24px 40px}
h1{font-size:1.6em;margin:.4em 0 .2em}h2{font-size:1.25em;border-bottom:2px solid #d0d7de;
 padding-bottom:.2em;margin-top:1.6em}
nav{font-size:.9em;margin:.4em 0 1em}nav a{margin-right:1em;color:#0b5cad;text-decoration:none}
table{border-collapse:collapse;margin:.6em 0;font-size:.88em;background:#fff}
th,td{border:1px solid #d0d7de;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#eef1f4}td.num{text-align:right;font-variant-numeric:tabular-nums;
 font-family:ui-monospace,Menlo,Consolas,monospace}
caption{caption-side:top;text-align:left;font-weight:600;padding:.3em 0}
figure{margin:.8em 0 1.4em;background:#fff;border:1px solid #d0d7de;padding:8px}
figure img{max-width:100%;height:auto;display:block}
figcaption{font-size:.88em;color:#333;margin-top:.4em}
ul.notes{padding-left:1.2em;font-size:.9em}ul.warning li{color:#8a4b00}ul.ok li{color:#1a7f37}
.verdict{display:inline-block;padding:2px 10px;border-radius:10px;font-weight:600}
.verdict.ok{background:#dafbe1;color:#1a7f37}.verdict.bad{background:#ffebe9;color:#a40e26}
.verdict.warn{background:#fff8c5;color:#7d4e00}
footer{font-size:.85em;color:#444}
.row{display:flex;flex-wrap:wrap;gap:0 28px;align-items:flex-start}
"""


def _attr(s: object) -> str:
    return html.escape(str(s), quote=True)


def _cell(c: str | Cell) -> str:
    if isinstance(c, str):
        return f"<td>{html.escape(c)}</td>"
    attrs = ""
    cls = ""
    if c.key is not None:
        attrs = f' data-key="{_attr(c.key)}" data-value="{_attr(c.value)}"'
        if c.scale != 1.0:
            attrs += f' data-scale="{c.scale!r}"'
        if isinstance(c.value, (int, float)) and not isinstance(c.value, bool):
            cls = ' class="num"'
    return f"<td{cls}{attrs}>{html.escape(c.text)}</td>"


def _table(t: Table) -> str:
    out = [f'<table id="{_attr(t.id)}">']
    if t.caption:
        out.append(f"<caption>{html.escape(t.caption)}</caption>")
    out.append("<thead><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in t.header)
               + "</tr></thead><tbody>")
    for row in t.rows:
        out.append("<tr>" + "".join(_cell(c) for c in row) + "</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _figure(f: Figure) -> str:
    data = "".join(f' data-{_attr(k)}="{_attr(v)}"' for k, v in f.data.items())
    if f.png is not None:
        img = (f'<img alt="{_attr(f.caption)}" src="data:image/png;base64,'
               f'{base64.b64encode(f.png).decode("ascii")}">')
    elif f.svg is not None:
        img = f.svg
    else:
        img = "<p>(no data)</p>"
    return (f'<figure id="{_attr(f.id)}"{data}>{img}<figcaption>{html.escape(f.caption)}'
            "</figcaption></figure>")


def _notes(n: Notes) -> str:
    items = "".join(f"<li>{html.escape(x)}</li>" for x in n.lines)
    return f'<ul id="{_attr(n.id)}" class="notes {_attr(n.kind)}">{items}</ul>'


def _block(b: Table | Figure | Notes | Row | str) -> str:
    if isinstance(b, Row):
        return '<div class="row">' + "".join(_block(x) for x in b.blocks) + "</div>"
    if isinstance(b, Table):
        return _table(b)
    if isinstance(b, Figure):
        return _figure(b)
    if isinstance(b, Notes):
        return _notes(b)
    return f"<p>{html.escape(b)}</p>"


def _provenance(p: Provenance) -> str:
    rows: list[list[str | Cell]] = [["tool", p.tool], ["command", p.command],
                                    ["started", p.started],
                                    ["run time", f"{p.seconds:.2f} s"]]
    rows += [[k, v] for k, v in p.extra]
    out = [_table(Table("provenance", ("what", "value"), rows, "How this report was made"))]
    files: list[list[str | Cell]] = [[f.path, f"{f.size_bytes}", f.sha256] for f in p.inputs]
    out.append(_table(Table("input-files", ("input file", "bytes", "sha256"),
                            files or [["(none recorded)", "", ""]], "Input files")))
    return "\n".join(out)


def render_html(title: str, sections: Sequence[Section], provenance: Provenance | None = None,
                subtitle: str = "", verdict: tuple[str, str] | None = None) -> str:
    """The page as one string.

    Args:
        title: page title and heading.
        sections: in order; a table of contents links to each.
        provenance: how it was made (a last section), or None.
        subtitle: a line under the heading.
        verdict: (text, ``ok``/``warn``/``bad``) shown as a badge under the heading.
    """
    head = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body><main>")
    body = [head, f"<h1>{html.escape(title)}</h1>"]
    if verdict is not None:
        body.append(f'<p><span id="verdict" class="verdict {_attr(verdict[1])}">'
                    f"{html.escape(verdict[0])}</span></p>")
    if subtitle:
        body.append(f"<p>{html.escape(subtitle)}</p>")
    toc = [(s.id, s.title) for s in sections] + ([("provenance-section", "How it was made")]
                                                 if provenance is not None else [])
    body.append("<nav>" + "".join(f'<a href="#{_attr(i)}">{html.escape(t)}</a>' for i, t in toc)
                + "</nav>")
    for s in sections:
        body.append(f'<section id="{_attr(s.id)}"><h2>{html.escape(s.title)}</h2>')
        if s.intro:
            body.append(f"<p>{html.escape(s.intro)}</p>")
        body.extend(_block(b) for b in s.blocks)
        body.append("</section>")
    if provenance is not None:
        body.append('<footer><section id="provenance-section"><h2>How it was made</h2>'
                    f"{_provenance(provenance)}</section></footer>")
    body.append("</main></body></html>\n")
    return "\n".join(body)


def _prefix_block(b: Any, prefix: str) -> Any:
    if isinstance(b, (Figure, Table, Notes)):
        return replace(b, id=prefix + b.id)
    if isinstance(b, Row):
        return Row([_prefix_block(x, prefix) for x in b.blocks])
    return b


def prefixed(sections: Sequence[Section], prefix: str) -> list[Section]:
    """Copies of ``sections`` with every element id prefixed (several results on one page)."""
    return [replace(s, id=prefix + s.id, blocks=[_prefix_block(b, prefix) for b in s.blocks])
            for s in sections]
