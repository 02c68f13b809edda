"""The not-a-knot cubic interpolating spline of the pose series (what the residual analysis
differentiates), without :mod:`scipy.interpolate`: importing it brings scipy.optimize and
scipy.spatial along (0.17 s of every ``diagnose``) for this one curve.

The arithmetic is scipy's ``CubicSpline(x, y, axis=0)`` with its default boundary condition,
step for step: the knot slopes from the same tridiagonal system (the same LAPACK solve), the
same piecewise coefficients, and each value by the same sum of powers; ``tests/test_spline.py``
asserts equality with scipy's, bit for bit.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_banded

Array = NDArray[np.float64]


class CubicSpline:
    """``y(x)`` through the points (``x`` strictly increasing, at least four; ``y`` (n, ...)),
    with the third derivative continuous at the second and the last but one knot; evaluated
    outside ``[x[0], x[-1]]`` by the end pieces."""

    def __init__(self, x: Array, y: Array) -> None:
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        n = len(x)
        if n < 4 or y.shape[0] != n:
            raise ValueError("a not-a-knot spline needs at least four points, one y per x")
        dx = np.diff(x)
        if np.any(dx <= 0.0):
            raise ValueError("x must be strictly increasing")
        dxr = dx.reshape((n - 1,) + (1,) * (y.ndim - 1))
        slope = np.diff(y, axis=0) / dxr
        A = np.zeros((3, n))
        b = np.empty(y.shape)
        A[1, 1:-1] = 2 * (dx[:-1] + dx[1:])
        A[0, 2:] = dx[:-1]
        A[-1, :-2] = dx[1:]
        b[1:-1] = 3 * (dxr[1:] * slope[:-1] + dxr[:-1] * slope[1:])
        A[1, 0] = dx[1]
        A[0, 1] = x[2] - x[0]
        d = x[2] - x[0]
        b[0] = ((dxr[0] + 2 * d) * dxr[1] * slope[0] + dxr[0] ** 2 * slope[1]) / d
        A[1, -1] = dx[-2]
        A[-1, -2] = x[-1] - x[-3]
        d = x[-1] - x[-3]
        b[-1] = (dxr[-1] ** 2 * slope[-2] + (2 * d + dxr[-1]) * dxr[-2] * slope[-1]) / d
        s = solve_banded((1, 1), A, b.reshape(n, -1), overwrite_ab=True, overwrite_b=True,
                         check_finite=False).reshape(b.shape)
        t = (s[:-1] + s[1:] - 2 * slope) / dxr
        self.x = x
        #: (4, n - 1, ...) coefficients of each piece, highest power first.
        self.c = np.stack((t / dxr, (slope - s[:-1]) / dxr - t, s[:-1], y[:-1]))

    def __call__(self, t: Array, nu: int = 0) -> Array:
        """The ``nu``-th derivative (0-3) at ``t`` (1-D)."""
        t = np.asarray(t, dtype=float)
        i = np.clip(np.searchsorted(self.x, t, side="right") - 1, 0, len(self.x) - 2)
        h = t - self.x[i]
        h = h.reshape(h.shape + (1,) * (self.c.ndim - 2))
        res: Array | float = 0.0
        z: Array | float = 1.0
        for k in range(nu, 4):  # power k of the piece, differentiated nu times
            factor = 1.0
            for j in range(k, k - nu, -1):
                factor *= j
            res = res + self.c[3 - k][i] * z * factor
            if k < 3:
                z = z * h
        out = np.asarray(res)
        out[np.isnan(t)] = np.nan  # as scipy's: no piece holds it
        return out
