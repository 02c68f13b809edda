"""``--html``: one self-contained page over the batch (the HTML report's batch view)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mocap_calib.io.yaml_io import load_yaml


def check_html_available() -> None:
    """The report needs matplotlib; importing the writer fails early when it is missing."""
    from mocap_calib.workflows.html.report import write_batch_report  # noqa: F401


def write_html(path: Path, sessions: list[dict[str, Any]], fleet_dir: Path) -> Path:
    from mocap_calib.workflows.html.report import write_batch_report

    fleet_file = fleet_dir / "fleet.yaml"
    fleet = load_yaml(fleet_file, "fleet summary") if fleet_file.is_file() else None
    return Path(write_batch_report(path, sessions, fleet))
