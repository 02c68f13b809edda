"""Compiled kernels: how the per-sample loops are compiled (numba), in one place.

The loops over the samples of a window (IMU integration, the window filter) are compiled once
per machine and cached on disk: a fresh process loads them in a fraction of a second instead of
compiling them again. They release the GIL, so the chunk threads of the window engine run them
in parallel.

The cache lives next to the sources (``__pycache__``) or, where the install is read-only, in the
user's cache folder (``NUMBA_CACHE_DIR`` overrides both). Where neither can be written, the
kernels are compiled in every process: slower to start, same numbers.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import numba
from numba.core.caching import FunctionCache

F = TypeVar("F", bound=Callable[..., Any])

_OPTIONS: dict[str, Any] = {"nogil": True, "error_model": "numpy", "boundscheck": False}


class _TolerantCache(FunctionCache):
    """A kernel cache whose failed write (disk full, folder gone read-only) costs only the
    compile time of the next process."""

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            super().save_overload(sig, data)
        except OSError as exc:
            warnings.warn(f"compiled kernel not cached ({exc}); the next run compiles it again",
                          RuntimeWarning, stacklevel=2)


def kernel(fn: F) -> F:
    """Compile ``fn`` with numba (no Python objects, GIL released), cached on disk."""
    disp = numba.njit(**_OPTIONS)(fn)
    try:
        disp._cache = _TolerantCache(fn)
    except RuntimeError:  # no writable cache folder: compile in every process
        pass
    return disp  # type: ignore[return-value]
