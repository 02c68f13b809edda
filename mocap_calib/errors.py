"""One exception tree for everything a user can get wrong or the data cannot support.

The CLI turns these into a one-line message and an exit code in one place
(:func:`mocap_calib.cli.main.main`); library users catch :class:`CalibrationError`.
"""

from __future__ import annotations


class CalibrationError(Exception):
    """Base class of every expected failure; its message is one line for the user."""

    exit_code = 1


class InputError(CalibrationError):
    """The input files or options are wrong (format, units, timestamps, overlap...)."""

    exit_code = 2


class ObservabilityError(CalibrationError):
    """The motion in the session cannot determine what was asked (static, too short...)."""

    exit_code = 3


class ConvergenceError(CalibrationError):
    """The solver did not reach a trustworthy solution."""

    exit_code = 4


class PlausibilityError(ConvergenceError):
    """The solver finished but its answer fails a physical plausibility check."""

    exit_code = 4


class Interrupted(CalibrationError):
    """Stopped by a signal (Ctrl-C: SIGINT, exit 130; SIGTERM, exit 143); nothing is written."""

    def __init__(self, signum: int) -> None:
        import signal

        name = signal.Signals(signum).name
        super().__init__(f"interrupted ({name}); no result was written")
        self.exit_code = 128 + int(signum)


def input_error(what: str, fix: str, source: str | None = None,
                row: int | None = None) -> InputError:
    """Build an :class:`InputError` whose message names the file, the row and the fix.

    Args:
        what: What is wrong, e.g. ``"timestamps are not increasing"``.
        fix: How to fix it, e.g. ``"sort the file by time"``.
        source: File (or stream) the problem is in.
        row: 1-based line number in the file, when one row is to blame.
    """
    where = ""
    if source is not None:
        where = f"{source}"
        if row is not None:
            where += f", line {row}"
        where += ": "
    return InputError(f"{where}{what}; {fix}")
