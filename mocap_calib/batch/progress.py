"""A one-line progress bar for a batch: sessions done and running, failures, ETA."""

from __future__ import annotations

import sys
from typing import TextIO

from mocap_calib.batch.runner import BatchProgress


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else \
        f"{s // 60}:{s % 60:02d}"


def render(p: BatchProgress, width: int = 24) -> str:
    filled = int(round(width * p.done / max(p.total, 1)))
    parts = [f"[{'#' * filled}{'.' * (width - filled)}] {p.done}/{p.total} done",
             f"{p.running} running"]
    if p.skipped:
        parts.append(f"{p.skipped} skipped")
    if p.failed:
        parts.append(f"{p.failed} failed")
    parts.append(f"ETA {_clock(p.eta_s)}")
    line = ", ".join(parts)
    return f"{line}  ({p.last})" if p.last else line


class ProgressBar:
    """Redraws one line on a terminal; elsewhere (a log file, CI) prints a line per event."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False) -> None:
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._width = 0

    def __call__(self, p: BatchProgress) -> None:
        if self.quiet:
            return
        line = render(p)
        if self.tty:
            pad = max(0, self._width - len(line))
            self.stream.write("\r" + line + " " * pad)
            self._width = len(line)
            if p.done == p.total:
                self.stream.write("\n")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
