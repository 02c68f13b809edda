"""Missing real recordings skip loudly locally and fail under CI (where they must be)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import shared_data


def test_missing_recording_fails_under_ci(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="missing"):
        shared_data("no_such_recording")


def test_missing_recording_skips_locally(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="missing"):
        shared_data("no_such_recording")


#: Three tests that need missing recordings (one through a fixture, as ``euroc_dir``), one
#: skipped for another reason and one that passes.
_PROBE = '''
import pytest
from conftest import shared_data

def test_needs_a():
    shared_data("no_such_recording_a")

@pytest.fixture
def rec_b():
    return shared_data("no_such_recording_b")

def test_needs_b(rec_b):
    pass

def test_needs_b_too(rec_b):
    pass

def test_skipped_for_another_reason():
    pytest.skip("nothing to do with recordings")

def test_passes():
    pass
'''


def _run_probe(tmp_path: Path, workers: str, ci: bool) -> subprocess.CompletedProcess[str]:
    """Run the probe with this suite's conftest in a fresh pytest (``-n 0`` or xdist)."""
    shutil.copy(Path(__file__).with_name("conftest.py"), tmp_path / "conftest.py")
    (tmp_path / "test_probe.py").write_text(_PROBE)
    env = {k: v for k, v in os.environ.items()
           if k not in ("CI", "PYTEST_ADDOPTS") and not k.startswith("PYTEST_XDIST")}
    if ci:
        env["CI"] = "true"
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", workers,
         "--rootdir", str(tmp_path), str(tmp_path)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("workers", ["0", "2"])
def test_summary_names_the_skipped_recordings(tmp_path: Path, workers: str) -> None:
    """The red line is printed with and without pytest-xdist (whose workers run the tests)."""
    run = _run_probe(tmp_path, workers, ci=False)
    assert run.returncode == 0, run.stdout + run.stderr
    line = [x for x in run.stdout.splitlines() if "real-data tests SKIPPED" in x]
    assert len(line) == 1, run.stdout
    assert " 3 real-data tests SKIPPED, missing: " in line[0] and line[0].startswith("!")
    assert "no_such_recording_a, " in line[0] and line[0].count("no_such_recording_b") == 1
    assert "4 skipped" in run.stdout and "1 passed" in run.stdout


@pytest.mark.parametrize("workers", ["0", "2"])
def test_missing_recordings_fail_the_run_under_ci(tmp_path: Path, workers: str) -> None:
    run = _run_probe(tmp_path, workers, ci=True)
    assert run.returncode == 1, run.stdout + run.stderr
    # The one in a fixture fails at setup: an error.
    assert "1 failed" in run.stdout and "2 errors" in run.stdout, run.stdout
    assert "1 skipped" in run.stdout and "1 passed" in run.stdout, run.stdout
    assert "real-data tests SKIPPED" not in run.stdout
