"""Where the scripts find the real recordings: ``../shared/data`` next to the repository, or,
from a git worktree elsewhere, next to the main working tree."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def shared_data() -> Path:
    """``../shared/data`` of this checkout (or of its main working tree), as it exists."""
    here = ROOT.parent / "shared" / "data"
    if here.is_dir():
        return here
    try:
        common = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--git-common-dir"],
                                capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return here
    main_tree = (ROOT / common).resolve().parent
    there = main_tree.parent / "shared" / "data"
    return there if there.is_dir() else here


DATA = shared_data()
