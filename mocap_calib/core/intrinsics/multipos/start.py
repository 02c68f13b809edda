"""Starting points of a raw-count calibration, found from the data (no units needed).

* Accelerometer: per-axis scale and offset from an ellipsoid through the static means
  (:func:`~mocap_calib.core.intrinsics.multipos.units.ellipsoid_start`).
* Gyroscope: one scale for all axes, the one whose integrated rotations best carry each static
  gravity direction onto the next. It is at least ``angle(u_j, u_j+1) / int |w - b| dt`` for
  every rotation ``j`` (a rotation turns gravity by at most its angle), so the scan starts
  near the median of these ratios and goes up by a factor 10; the best grid point is then
  refined by a bounded 1-D search. Scales that over-wind the rotations by a turn give local
  minima only beyond twice the true scale, with residuals far above the true one.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from mocap_calib.core.model import so3
from mocap_calib.core.model.preint import quat_increments, quat_product, sample_nodes

Array = NDArray[np.float64]

#: Grid of the gyro scale scan, as multiples of its lower bound.
_GRID = np.geomspace(0.9, 10.0, 90)


def _direction_error(scale: float, w: Array, dt_pad: Array, u_start: Array,
                     u_end: Array) -> float:
    q = quat_product(quat_increments(sample_nodes(scale * w), dt_pad))
    pred = np.einsum("mji,mj->mi", so3.quat_to_rotmat(q), u_start)
    return float(np.sum((pred - u_end) ** 2))


def gyro_start_scale(w: Array, dt_pad: Array, u_start: Array, u_end: Array,
                     candidates: tuple[float, ...] = ()) -> float:
    """Isotropic gyro scale (SI per input unit) that best explains the rotations.

    Args:
        w: (m, L+1, 3) bias-free gyro of each rotation in input units, padded.
        dt_pad: (m, L) step lengths (0 in the padding).
        u_start: (m, 3) gravity direction before each rotation (unit vectors).
        u_end: (m, 3) gravity direction after.
        candidates: further scales to try (e.g. a nominal one); the best of all wins.

    Returns:
        The scale; NaN if the gyro shows no rotation.
    """
    turned = np.sum(np.linalg.norm(w[:, :-1], axis=-1) * dt_pad, axis=1)
    seen = np.arccos(np.clip(np.sum(u_start * u_end, axis=1), -1.0, 1.0))
    ok = turned > 0
    if not ok.any():
        return float("nan")
    # The median, not the largest, ratio: a short gap between two intervals of one pose has a
    # noise-only "rotation" whose ratio means nothing.
    lower = float(np.median(seen[ok] / turned[ok]))
    if not lower > 0:
        lower = float(np.median(np.pi / turned[ok]))
    grid = lower * _GRID
    cost = [_direction_error(s, w, dt_pad, u_start, u_end) for s in grid]
    i = int(np.argmin(cost))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    res = minimize_scalar(_direction_error, bounds=(lo, hi), method="bounded",
                          args=(w, dt_pad, u_start, u_end), options={"xatol": 1e-9 * hi})
    best, best_cost = float(res.x), float(res.fun)
    for s in candidates:
        c = _direction_error(s, w, dt_pad, u_start, u_end)
        if c < best_cost:
            best, best_cost = float(s), c
    return best
