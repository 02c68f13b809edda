"""Stop requests (Ctrl-C, SIGTERM), raised as :class:`~mocap_calib.errors.Interrupted` where
that is safe.

A Python signal handler runs in the main thread between two bytecodes, wherever they are: also
inside a Python callback that GTSAM's C++ code called (a ``CustomFactor``), where an exception
would have to unwind through C++ frames. So :func:`handle` records the request and raises only
when no such callback is on the stack; the solver loops call :func:`check` after every call
into GTSAM (between LM iterations), and the batched factors stop evaluating once a stop is
requested, so the solver returns within an evaluation. The request stays set until
:func:`reset`: a caller that catches :class:`Interrupted` by mistake (as one of many
:class:`~mocap_calib.errors.CalibrationError`) is stopped again at the next check.

Without :func:`handle` installed (library use) nothing here ever raises: Ctrl-C is Python's
KeyboardInterrupt as usual.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import CodeType, FrameType
from typing import TypeVar

from mocap_calib.errors import Interrupted

_REQUEST: list[int] = []  # the signal number, once a stop is requested
_CALLBACKS: set[CodeType] = set()  # code of the functions C++ calls back
_DEFERRED: list[int] = [0]  # depth of deferred() blocks

F = TypeVar("F", bound=Callable[..., object])


def request(signum: int) -> None:
    """Ask for a stop (the first signal's number is kept)."""
    if not _REQUEST:
        _REQUEST.append(int(signum))


def requested() -> bool:
    """A stop has been requested."""
    return bool(_REQUEST)


def reset() -> None:
    """Forget a request (a new command starts)."""
    _REQUEST.clear()


def check() -> None:
    """Raise :class:`Interrupted` if a stop has been requested; call it between steps."""
    if _REQUEST:
        raise Interrupted(_REQUEST[0])


def called_from_native(fn: F) -> F:
    """Mark ``fn`` as a callback that C++ calls (a GTSAM ``CustomFactor`` function): a signal
    that arrives while it runs only records the request."""
    _CALLBACKS.add(fn.__code__)  # type: ignore[attr-defined]
    return fn


@contextmanager
def deferred() -> Iterator[None]:
    """A block that a signal does not cut in two (a file written and its status recorded): a
    stop requested inside it is raised at its end."""
    _DEFERRED[0] += 1
    try:
        yield
    finally:
        _DEFERRED[0] -= 1
    check()


def _in_callback(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_code in _CALLBACKS:
            return True
        frame = frame.f_back
    return False


def handle(signum: int, frame: FrameType | None) -> None:
    """Signal handler: record the stop, and raise it at once unless C++ is on the way out or a
    :func:`deferred` block runs."""
    request(signum)
    if not _DEFERRED[0] and not _in_callback(frame):
        raise Interrupted(signum)
