"""How a position problem's windows are split into chunks for the threads
(:mod:`mocap_calib.core.threads`).

The window engine's loops are compiled and release the GIL (so does most of its numpy work), so
chunks of windows evaluate in parallel on the cores. Each window is computed on its own, so the
split does not change the numbers beyond rounding; it depends on the windows only, never on the
machine, so that the same session gives the same numbers everywhere; only the number of threads
that run the chunks does.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Fewest windows per chunk when a problem is split in two for the threads: on fewer, the
#: per-chunk overhead (a few ms of numpy calls) outweighs the second core.
MIN_CHUNK_WINDOWS = 4


def split_windows(W: int, steps: int, chunk_steps: int, split: bool) -> list[NDArray[np.int64]]:
    """Window indices per chunk: chunks of about ``chunk_steps`` samples (memory), and with
    ``split`` an even number of them (the two threads) once there are windows enough."""
    n = -(-W // max(1, chunk_steps // max(1, steps)))
    if split and W >= 2 * MIN_CHUNK_WINDOWS:
        n = max(2, n + n % 2)
    per = -(-W // n)
    return [np.arange(i, min(i + per, W)) for i in range(0, W, per)]
