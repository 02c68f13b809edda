"""How a result was made, for the HTML reports: version, command line, input files with sizes
and SHA-256, start time and run time."""

from __future__ import annotations

import hashlib
import platform
import shlex
import sys
import time
from collections.abc import Iterable
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import mocap_calib

if TYPE_CHECKING:  # the HTML pages' module, imported when a report is written
    from mocap_calib.report.html.page import InputFile, Provenance

#: The command line as the CLI received it (set by ``cli.main``); None: use ``sys.argv``.
_COMMAND: list[str] | None = None
#: Files under an input folder that are hashed (data and sensor descriptions, not images).
DATA_SUFFIXES = {".csv", ".txt", ".yaml", ".yml", ".bag", ".db3", ".mcap", ".ulg", ".json",
                 ".tum"}
MAX_FILES_PER_FOLDER = 40


def record_command_line(argv: list[str]) -> None:
    """Remember the arguments of this CLI run (the reports show them)."""
    global _COMMAND
    _COMMAND = list(argv)


def command_line() -> str:
    args = _COMMAND if _COMMAND is not None else sys.argv[1:]
    return shlex.join(["mocap-calib", *args])


def sha256(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def input_files(paths: Iterable[Path | str | None]) -> list[InputFile]:
    """Sizes and hashes of the input files; a folder contributes its data files (sorted)."""
    from mocap_calib.report.html.page import InputFile

    out: list[InputFile] = []
    seen: set[Path] = set()
    for p in paths:
        if p is None:
            continue
        path = Path(p)
        if path.is_dir():
            files = sorted(f for f in path.rglob("*")
                           if f.is_file() and f.suffix.lower() in DATA_SUFFIXES)
            files = files[:MAX_FILES_PER_FOLDER]
        elif path.is_file():
            files = [path]
        else:
            continue
        for f in files:
            if f.resolve() in seen:
                continue
            seen.add(f.resolve())
            out.append(InputFile(str(f), f.stat().st_size, sha256(f)))
    return out


class RunClock:
    """Start time of a command, for its report's provenance."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.started = datetime.now().astimezone().isoformat(timespec="seconds")

    def seconds(self) -> float:
        return time.perf_counter() - self.t0


def provenance(paths: Iterable[Path | str | None], clock: RunClock) -> Provenance:
    """The provenance of a run that read ``paths`` and started at ``clock``."""
    import numpy

    from mocap_calib.report.html.page import Provenance

    return Provenance(
        tool=f"mocap-calib {mocap_calib.__version__}", command=command_line(),
        inputs=input_files(paths), started=clock.started, seconds=clock.seconds(),
        extra=[("python", platform.python_version()), ("numpy", numpy.__version__),
               ("platform", platform.platform(terse=True))])
