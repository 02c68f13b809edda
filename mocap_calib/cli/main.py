"""``mocap-calib`` entry point: one typer app; each command lives in its own module.

Commands only parse options, call one library function and write its output. Every expected
failure is a :class:`~mocap_calib.errors.CalibrationError`; :func:`main` turns it into a one-line
message on stderr and the error's exit code, here and nowhere else.
"""

from __future__ import annotations

import os
import sys

import typer

from mocap_calib.cli.common import Group
from mocap_calib.errors import CalibrationError, InputError, ObservabilityError

app = typer.Typer(
    cls=Group,
    name="mocap-calib",
    help="Calibrate an IMU from motion-capture sessions (EuRoC/ASL CSVs, TUM, generic CSV, ROS "
    "bags, MCAP, PX4 ULog, Motive and Vicon exports).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

INTERNAL_ERROR_EXIT = 70


@app.callback()
def _group() -> None:
    # A callback keeps the app a group of commands even when only one is registered.
    pass


def _register_commands(args: list[str] | None = None) -> None:
    """The command named first in ``args`` only (start-up of that command's imports alone);
    every command without ``args``, for the top-level help or an unknown name."""
    from mocap_calib.cli.commands import COMMANDS, register

    name = next((a for a in args or [] if not a.startswith("-")), None)
    register((name,) if name in COMMANDS else COMMANDS)


def _refuse_repeated(args: list[str]) -> None:
    """click keeps the last of a repeated single-value option silently: refuse it instead."""
    from mocap_calib.cli.build import repeated_options

    group = typer.main.get_command(app)
    command = getattr(group, "commands", {}).get(args[0]) if args else None
    if command is None:
        return
    repeated = repeated_options(command, args[1:])
    if repeated:
        several = [p.opts[0] for p in command.params if getattr(p, "multiple", False)]
        may = f" (only {', '.join(several)} may repeat)" if several else ""
        raise InputError(f"{repeated[0]} is given more than once; it takes one value: give it "
                         f"once{may}")


def _is_usage_error(err: BaseException) -> bool:
    """click's usage errors (bad option, missing argument): they can show themselves and carry
    an exit code. Recognised by that, not by click's class, whose module typer vendors."""
    return callable(getattr(err, "show", None)) and isinstance(getattr(err, "exit_code", None),
                                                                int)


def _usage_line(err: BaseException) -> str:
    """click's usage error as one line, with where to look."""
    text = " ".join(str(getattr(err, "format_message", lambda: err)()).split())
    text = text.replace("Value error, ", "")
    ctx = getattr(err, "ctx", None)
    where = getattr(ctx, "command_path", None) if ctx is not None else None
    return f"{text} (see '{where} --help')" if where else text


def _is_indeterminate(err: BaseException) -> bool:
    """GTSAM's indeterminate-system exception (a RuntimeError with a multi-line text), wherever
    a solver outside the wrapped calls raises it."""
    text = str(err)
    return isinstance(err, RuntimeError) and ("ndeterminant" in text or "ndeterminate" in text)


def _one_malloc_arena() -> None:
    """One glibc malloc arena for the process, set before any thread starts. Otherwise the
    window chunks' threads get arenas of their own whose freed memory the main thread never
    reuses (measured peaks: 735 MB on a 60-min session with one arena, 790-817 MB with one per
    thread; 10 min: 330 and 353 MB; no slower). An explicit MALLOC_ARENA_MAX wins; elsewhere
    than glibc nothing changes."""
    if "MALLOC_ARENA_MAX" in os.environ or not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt  # glibc's; musl has none
    except (OSError, AttributeError):
        return
    mallopt(-8, 1)  # M_ARENA_MAX


def _names_as_given() -> None:
    """File names with bytes that are not UTF-8 reach Python as lone surrogates, which a
    strict stream (the default outside the C locale) cannot print: the run would end with exit
    70 after writing its files. stdout writes them back as their original bytes."""
    reconfigure = getattr(sys.stdout, "reconfigure", None)
    if reconfigure is not None and getattr(sys.stdout, "errors", None) == "strict":
        reconfigure(errors="surrogateescape")


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return (and exit with) its exit code."""
    _one_malloc_arena()
    _names_as_given()
    debug = os.environ.get("MOCAP_CALIB_DEBUG", "") not in ("", "0")
    from mocap_calib.workflows.interrupts import stop_on_signals
    from mocap_calib.workflows.report_files.provenance import record_command_line

    record_command_line(list(sys.argv[1:] if argv is None else argv))  # for the HTML reports
    try:
        with stop_on_signals():
            _register_commands(list(sys.argv[1:] if argv is None else argv))
            _refuse_repeated(list(sys.argv[1:] if argv is None else argv))
            app(args=argv, standalone_mode=False)
        code = 0
    except CalibrationError as err:
        if debug:
            raise
        print(f"error: {err}", file=sys.stderr)
        code = err.exit_code
    except typer.Exit as ex:  # --help, explicit exits
        code = ex.exit_code
    except (typer.Abort, KeyboardInterrupt):
        print("error: interrupted; no result was written", file=sys.stderr)
        code = 130
    except Exception as err:  # click usage errors and anything unexpected
        if _is_indeterminate(err) and not debug:
            print("error: the data do not determine every parameter (GTSAM: indeterminate "
                  "linear system); check the inputs' units and conventions, or record motion "
                  "about all axes", file=sys.stderr)
            code = ObservabilityError.exit_code
        elif _is_usage_error(err):
            print(f"error: {_usage_line(err)}", file=sys.stderr)
            code = err.exit_code  # type: ignore[attr-defined]
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
        _end_process(code)
    return code


def _end_process(code: int) -> None:
    """End the process once its work is done and its files are written and closed: streams
    flushed and the exit handlers run, without the interpreter's teardown. The teardown only
    frees memory the system takes back anyway, and LLVM's and GTSAM's C++ destructors read
    ~50 MB of their code back into memory for it (a run's peak memory, on a short session)."""
    import atexit

    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can be said
            pass
    atexit._run_exitfuncs()
    os._exit(code)


if __name__ == "__main__":
    main()
