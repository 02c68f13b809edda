"""``--html``: the hook through which the HTML report (issue 13) shows a batch.

Contract for the report layer: ``mocap_calib.report.html.write_batch_report(path, sessions,
fleet)`` writes one self-contained HTML file and returns its path; ``sessions`` is the list of
``OUT/batch.yaml`` session entries (plain dicts, results under ``OUT/<id>/calib.yaml``) and
``fleet`` the plain data of ``OUT/fleet/fleet.yaml`` (``None`` when nothing succeeded). Until
that function exists, ``--html`` stops before any work with a one-line message.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import yaml

from mocap_calib.errors import InputError

_MODULE, _FUNCTION = "mocap_calib.report.html", "write_batch_report"


def _writer() -> Any:
    try:
        module = importlib.import_module("mocap_calib.report.html")
    except ModuleNotFoundError:
        return None
    return getattr(module, _FUNCTION, None)


def check_html_available() -> None:
    if _writer() is None:
        raise InputError("--html: this version has no HTML batch report yet "
                         f"({_MODULE}.{_FUNCTION}); drop --html and read OUT/batch.yaml and "
                         "OUT/fleet/")


def write_html(out_dir: Path, sessions: list[dict[str, Any]], fleet_dir: Path) -> Path:
    writer = _writer()
    if writer is None:
        check_html_available()
    fleet_file = fleet_dir / "fleet.yaml"
    fleet = yaml.safe_load(fleet_file.read_text()) if fleet_file.is_file() else None
    return Path(writer(out_dir / "batch.html", sessions, fleet))
