"""Ctrl-C (SIGINT) and SIGTERM stop a run with exit 130 / 143, write no result and leave an
existing output file untouched, whether the signal comes while reading or while solving."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mocap_calib.workflows.simulate import simulate_to_folder

ENTRY = Path(sys.executable).parent / "mocap-calib"


@pytest.fixture(scope="module")
def long_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("long")
    simulate_to_folder(out, seed=11, duration=240.0)
    return out


@pytest.mark.parametrize(("sig", "code", "when", "command"), [
    (signal.SIGINT, 130, "start", "calibrate"),  # while starting up and reading the inputs
    (signal.SIGINT, 130, "stage 3/3", "calibrate"),  # while solving
    (signal.SIGTERM, 143, "stage 3/3", "calibrate"),
    (signal.SIGINT, 130, "starting model", "diagnose"),  # other commands stop the same way
])
def test_signal_stops_without_writing(long_session: Path, tmp_path: Path, sig: int, code: int,
                                      when: str, command: str) -> None:
    out = tmp_path / "calib.yaml"
    out.write_text("previous result\n")
    report = ["--report", str(tmp_path / "r.txt")] if command == "calibrate" else []
    proc = subprocess.Popen([str(ENTRY), command, str(long_session), "--out", str(out),
                             *report],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reached = threading.Event()

    def read() -> None:
        for line in proc.stderr:  # progress lines
            lines.append(line)
            if when in line or "noise" in line and when == "start":
                reached.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    if when == "start":
        time.sleep(1.0)  # past Python's own start-up, before the first stage
    else:
        assert reached.wait(60), "".join(lines)
    assert proc.poll() is None, "the run finished before the signal"
    proc.send_signal(sig)
    stdout = proc.stdout.read()
    proc.wait(timeout=60)
    reader.join(5)
    stderr = "".join(lines)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stdout + stderr
    assert "interrupted" in stderr.splitlines()[-1]
    if when == "start":
        assert not any("stage" in x for x in lines), "signal came too late to test start-up"
    assert out.read_text() == "previous result\n"
    assert not (tmp_path / "r.txt").exists()
    assert not list(tmp_path.glob(".*tmp"))
