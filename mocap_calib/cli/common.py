"""Terminal output helpers shared by the commands: progress lines, and the help pages' command
classes."""

from __future__ import annotations

import sys
import time
from typing import Any

from typer.core import TyperCommand, TyperGroup


class Progress:
    """One line per step on stderr, with the elapsed time (quiet: nothing)."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.t0 = time.perf_counter()

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.1f} s] {message}", file=sys.stderr,
                  flush=True)


class _BareHelpFlag:
    """The help page lists every option with its type; typer's own ``--help`` flag, like the
    commands' flags, shows none (else ``<bool>``)."""

    def get_help_option(self, ctx: Any) -> Any:
        option = super().get_help_option(ctx)  # type: ignore[misc]
        if option is not None:
            option.metavar = ""
        return option


class Command(_BareHelpFlag, TyperCommand):
    """A command whose help page shows ``--help`` without a type."""


class Group(_BareHelpFlag, TyperGroup):
    """The app's group, whose help page shows ``--help`` without a type."""
