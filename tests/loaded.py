"""Which modules a piece of code loads, run in a fresh interpreter (import-cost tests)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterable


def loaded_by(code: str, packages: Iterable[str]) -> list[str]:
    """The modules of ``packages`` (top-level names, or exact module names) that are loaded
    after running ``code`` in a new process, sorted; fails the test if ``code`` fails."""
    wanted = sorted(set(packages))
    probe = (f"{code}\nimport sys\nwanted = {wanted!r}\n"
             "print('\\n'.join(sorted(m for m in sys.modules if m in wanted "
             "or m.split('.')[0] in wanted)))\n")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split()
