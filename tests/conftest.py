"""Shared test helpers: where the real recordings are, and loud skipping when they are absent.

The recordings live in ``../shared/data`` next to the repository (never copied into it). Tests
that need them use :func:`shared_data`: without the folder they skip, and the session summary
says how many did; with ``CI=true`` a missing folder fails them instead, because CI has it.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
_SKIPPED: list[str] = []


def shared_data(*parts: str) -> Path:
    """Path under ``../shared/data``; skip (or fail under CI) when it is missing."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        msg = f"real recording {path} is missing (expected ../shared/data next to the repo)"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(msg)
        _SKIPPED.append(str(path))
        pytest.skip(msg)
    return path


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _SKIPPED:
        missing = ", ".join(sorted(set(_SKIPPED)))
        terminalreporter.write_sep("!", f"{len(_SKIPPED)} real-data tests SKIPPED, missing: "
                                        f"{missing}", red=True, bold=True)


@pytest.fixture
def euroc_dir() -> Path:
    """``../shared/data/euroc_V2_03_difficult`` (holds ``mav0``)."""
    return shared_data("euroc_V2_03_difficult", "mav0").parent


@pytest.fixture
def broad21_csv() -> Path:
    """BROAD trial 21's one-file CSV."""
    return shared_data("broad_21_undisturbed_fast_combined", "data.csv")
