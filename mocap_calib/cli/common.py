"""Terminal output helpers shared by the commands."""

from __future__ import annotations

import sys
import time


class Progress:
    """One line per step on stderr, with the elapsed time (quiet: nothing)."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.t0 = time.perf_counter()

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.1f} s] {message}", file=sys.stderr,
                  flush=True)
