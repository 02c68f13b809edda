"""Self-contained HTML reports (inline PNG plots by matplotlib, no external references).

Generic: :func:`render_html` takes :class:`Section` lists (tables, figures,
notes) and a :class:`Provenance`; :func:`prefixed` makes the ids of sections unique when several
results share one page. Per result kind: :func:`calibration_sections`,
:func:`diagnosis_sections`, :func:`multipos_sections`, :func:`allan_sections`,
:func:`batch_sections`. The files are read and the figures computed in the workflow layer
(``mocap_calib.workflows.report_files.pages``, e.g. ``write_batch_report``), and written there
through ``mocap_calib.io.atomic``.
matplotlib is imported only when a figure is drawn.
"""

from __future__ import annotations

from mocap_calib.report.html.page import (
    Cell,
    Figure,
    InputFile,
    Notes,
    Provenance,
    Row,
    Section,
    Table,
    prefixed,
    render_html,
)
from mocap_calib.report.html.sections import (
    allan_sections,
    batch_sections,
    calibration_sections,
    diagnosis_sections,
    multipos_sections,
    take_sections,
)

__all__ = ["Cell", "Figure", "InputFile", "Notes", "Provenance", "Row", "Section", "Table",
           "render_html", "prefixed", "calibration_sections",
           "diagnosis_sections", "multipos_sections", "allan_sections", "batch_sections",
           "take_sections"]
