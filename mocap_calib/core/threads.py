"""The threads the calibration's vectorised work runs on: the window engine's chunks, and the
row blocks of the session-long arrays the first fits screen (their numpy work and compiled
loops release the GIL, so blocks run on the cores in parallel).

Every block is computed on its own, so the split never changes the numbers; it depends on the
data only, never on the machine; only the number of threads that run the blocks does.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

_PREFIX = "calibration-blocks"
_POOL: list[ThreadPoolExecutor | None] = []
_THREADS = [min(2, os.cpu_count() or 1)]


def set_chunk_threads(n: int) -> int:
    """Run blocks on ``n`` threads (1: in the calling thread); returns the previous count.
    A batch that already runs one session per core sets 1 in its workers: nested threads would
    only contend."""
    previous, _THREADS[0] = _THREADS[0], max(1, int(n))
    _POOL.clear()
    return previous


def chunk_pool() -> ThreadPoolExecutor | None:
    """The threads that run blocks (None with one)."""
    if not _POOL:
        n = _THREADS[0]
        _POOL.append(ThreadPoolExecutor(n, thread_name_prefix=_PREFIX) if n > 1 else None)
    return _POOL[0]


def map_blocks(fn: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """``[fn(i) for i in items]``, on the threads when there are several items (in the calling
    thread when it is one of them: a block never waits for a block behind it)."""
    pool = chunk_pool()
    if pool is None or len(items) < 2 or threading.current_thread().name.startswith(_PREFIX):
        return [fn(i) for i in items]
    return list(pool.map(fn, items))


def beside(background: Callable[[], T], foreground: Callable[[], R]) -> tuple[T, R]:
    """``(background(), foreground())``, the first on a thread of its own while the calling
    thread runs the second (each may still run blocks on the threads); an error of either
    is raised, the foreground's first."""
    with ThreadPoolExecutor(1, thread_name_prefix="beside") as ex:
        job = ex.submit(background)
        try:
            out = foreground()
        except BaseException:
            job.cancel()
            raise
        return job.result(), out


# A forked child has none of the parent's threads: it starts its own pool.
os.register_at_fork(after_in_child=_POOL.clear)
