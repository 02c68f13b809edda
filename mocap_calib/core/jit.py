"""Compiled kernels: how the per-sample loops are compiled (numba), in one place.

The loops over the samples of a window (IMU integration, the window filter) are compiled once
per machine and cached on disk: a fresh process loads them in a fraction of a second instead of
compiling them again. They release the GIL, so the chunk threads of the window engine run them
in parallel. The install scripts compile them (``mocap-calib compile``), so that no user's run
does.

The cache lives next to the sources (``__pycache__``) or, where the install is read-only, in the
user's cache folder (``NUMBA_CACHE_DIR`` overrides both). Where neither can be written, the
kernels are compiled in every process: slower to start, same numbers.

LLVM (the compiler behind numba) is one library of ~180 MB whose start-up touches about half of
its code; once a kernel is loaded none of that code runs again until the next kernel loads.
After each load or compile those pages are handed back to the system (they are clean pages of
the library file: the system can read them again, and does if another kernel loads), which
takes ~90 MB off the resident memory of a run.
"""

from __future__ import annotations

import re
import sys
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import numba
from numba.core.caching import FunctionCache

F = TypeVar("F", bound=Callable[..., Any])

_OPTIONS: dict[str, Any] = {"nogil": True, "error_model": "numpy", "boundscheck": False}

#: The signatures loaded from the cache in this process.
_LOADS: list[Any] = []

#: Every kernel made by :func:`kernel`, in the order their modules defined them.
KERNELS: list[Any] = []

#: A mapping's first line in /proc/self/smaps: start, end, permissions, path.
_MAPPING = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) (\S+) \S+ \S+ \S+ *(.*)$", re.M)
_ANONYMOUS = re.compile(r"^Anonymous: +(\d+)", re.M)

#: The library whose pages :func:`release_compiler_pages` hands back (its file name's start).
_COMPILER_LIBRARY = "libllvmlite"
#: Its clean read-only mappings, once found (see :func:`release_compiler_pages`).
_SPANS: list[tuple[int, int]] = []


class _TolerantCache(FunctionCache):
    """A kernel cache whose failed write (disk full, folder gone read-only) costs only the
    compile time of the next process; after a load or a save the compiler's pages are released
    (:func:`release_compiler_pages`)."""

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        if not _LOADS:
            _start_runtime(target_context)
        _LOADS.append(sig)
        data = super().load_overload(sig, target_context)
        release_compiler_pages()
        return data

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            super().save_overload(sig, data)
        except OSError as exc:
            warnings.warn(f"compiled kernel not cached ({exc}); the next run compiles it again",
                          RuntimeWarning, stacklevel=2)
        release_compiler_pages()


def _start_runtime(target_context: Any) -> None:
    """Before the first load: the compiler pages touched since numba's import go back, numba's
    runtime compiles its own helpers (LLVM's optimiser runs once per process) and those pages
    go back too, so that they are not resident while the first load imports the rest of numba
    (and scipy.linalg, through it)."""
    release_compiler_pages()
    try:
        from numba.core.runtime.nrt import rtsys
    except ImportError:  # another numba: its first load starts the runtime itself
        return
    rtsys.initialize(target_context)
    release_compiler_pages()


def kernel(fn: F | None = None, *, inline: bool = False) -> Any:
    """Compile ``fn`` with numba (no Python objects, GIL released), cached on disk. With
    ``inline`` (``@kernel(inline=True)``) a compiled caller gets the function's body in place
    of a call: a call passes every array argument with two atomic reference counts, which in
    a per-sample loop cost more than the arithmetic (at most 31 arguments: numba's inliner)."""
    if fn is None:
        return lambda f: kernel(f, inline=inline)
    disp = numba.njit(**_OPTIONS, **({"inline": "always"} if inline else {}))(fn)
    try:
        disp._cache = _TolerantCache(fn)
    except RuntimeError:  # no writable cache folder: compile in every process
        pass
    KERNELS.append(disp)
    return disp


def kernel_name(disp: Any) -> str:
    """``module.function`` of a kernel."""
    return f"{disp.py_func.__module__}.{disp.py_func.__name__}"


def compiled_in_process() -> list[str]:
    """The kernels this process compiled (no cached copy for their argument types), each as
    ``module.function``; loaded ones are not listed."""
    return [kernel_name(d) for d in KERNELS if sum(d.stats.cache_misses.values())]


def loaded_in_process() -> list[str]:
    """The kernels this process loaded from the cache."""
    return [kernel_name(d) for d in KERNELS if sum(d.stats.cache_hits.values())]


def uncached_kernels() -> list[str]:
    """The kernels without a writable cache folder (compiled in every process)."""
    return [kernel_name(d) for d in KERNELS if not isinstance(d._cache, _TolerantCache)]


def release_compiler_pages() -> int:
    """Hand the resident pages of the compiler library's read-only mappings back to the system
    (Linux; elsewhere nothing happens). Only mappings that hold no page of their own
    (``Anonymous: 0``: code and constants as the file has them, never the relocated data) are
    released; a page that is used again is read back from the file cache. Returns the bytes of
    the mappings released."""
    if not sys.platform.startswith("linux"):
        return 0
    global _SPANS
    try:
        # The library's read-only mappings and whether they hold a private page are fixed
        # once it is loaded (relocation is done then): read them once (7 ms a read).
        spans = _SPANS if _SPANS else _clean_spans(_COMPILER_LIBRARY)
    except OSError:
        return 0
    _SPANS = spans
    if not spans:
        return 0
    import ctypes

    try:
        madvise = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):
        return 0
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    done = 0
    for start, end in spans:
        if madvise(start, end - start, 4) == 0:  # MADV_DONTNEED
            done += end - start
    return done


def _clean_spans(library: str) -> list[tuple[int, int]]:
    """Address ranges of the read-only mappings of ``library`` that hold no private page."""
    with open("/proc/self/smaps", encoding="ascii", errors="replace") as f:
        text = f.read()
    heads = list(_MAPPING.finditer(text))
    spans: list[tuple[int, int]] = []
    for k, head in enumerate(heads):
        lo, hi, perms, path = head.groups()
        if "w" in perms or not path.rpartition("/")[2].startswith(library):
            continue
        body = text[head.end():heads[k + 1].start() if k + 1 < len(heads) else len(text)]
        anonymous = _ANONYMOUS.search(body)
        if anonymous is not None and anonymous.group(1) == "0":
            spans.append((int(lo, 16), int(hi, 16)))
    return spans


release_compiler_pages()  # the pages numba's import touched
