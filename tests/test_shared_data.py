"""Missing real recordings skip loudly locally and fail under CI (where they must be)."""

from __future__ import annotations

import conftest
import pytest
from conftest import shared_data


@pytest.fixture(autouse=True)
def _keep_the_summary_honest(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(conftest, "_SKIPPED", [])  # these probes are not real-data tests


def test_missing_recording_fails_under_ci(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="missing"):
        shared_data("no_such_recording")


def test_missing_recording_skips_locally(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="missing"):
        shared_data("no_such_recording")
