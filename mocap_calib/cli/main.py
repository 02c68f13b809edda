"""``mocap-calib`` entry point: one typer app; each command lives in its own module.

Commands only parse options, call one library function and write its output. Every expected
failure is a :class:`~mocap_calib.errors.CalibrationError`; :func:`main` turns it into a one-line
message on stderr and the error's exit code, here and nowhere else.
"""

from __future__ import annotations

import os
import sys

import typer

from mocap_calib.errors import CalibrationError

app = typer.Typer(
    name="mocap-calib",
    help="Calibrate an IMU from motion-capture sessions (EuRoC/ASL CSVs, TUM, generic CSV).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

INTERNAL_ERROR_EXIT = 70


def _register_commands() -> None:
    # Imported for their side effect of adding commands to ``app``.
    from mocap_calib.cli import commands  # noqa: F401


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return (and exit with) its exit code."""
    _register_commands()
    debug = os.environ.get("MOCAP_CALIB_DEBUG", "") not in ("", "0")
    try:
        rv = app(args=argv, standalone_mode=False)
        # typer turns Ctrl-C into Exit(130) and, not standalone, returns that code
        code = rv if isinstance(rv, int) else 0
        if code == 130:
            print("error: interrupted", file=sys.stderr)
    except CalibrationError as err:
        if debug:
            raise
        print(f"error: {err}", file=sys.stderr)
        code = err.exit_code
    except typer.Exit as ex:  # --help, explicit exits
        code = ex.exit_code
    except (typer.Abort, KeyboardInterrupt):
        print("error: interrupted", file=sys.stderr)
        code = 130
    except Exception as err:  # click usage errors and anything unexpected
        from typer._click.exceptions import ClickException

        if isinstance(err, ClickException):
            err.show()
            code = err.exit_code
        elif isinstance(err, MemoryError):
            print("error: out of memory; calibrate a shorter part of the session "
                  "(--start/--end)", file=sys.stderr)
            code = INTERNAL_ERROR_EXIT
        else:
            if debug:
                raise
            print(f"internal error: {type(err).__name__}: {err} (a bug in mocap-calib; rerun "
                  "with MOCAP_CALIB_DEBUG=1 for the traceback and report it)", file=sys.stderr)
            code = INTERNAL_ERROR_EXIT
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
