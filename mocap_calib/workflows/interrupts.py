"""Ctrl-C and SIGTERM for a command: they stop it with :class:`~mocap_calib.errors.Interrupted`
(exit 130 / 143) within about a second, wherever it is (see :mod:`mocap_calib.core.interrupt`).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from mocap_calib.core import interrupt

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """While the block runs, SIGINT and SIGTERM raise :class:`Interrupted` (not Python's
    KeyboardInterrupt, which click would turn into an exit code of its own), so every command
    stops the same way and writes nothing: outputs are written atomically, at the end."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    interrupt.reset()
    old = {s: signal.getsignal(s) for s in SIGNALS}
    for s in SIGNALS:
        signal.signal(s, interrupt.handle)
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        interrupt.reset()
