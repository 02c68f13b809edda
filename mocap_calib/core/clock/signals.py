"""The signals the coarse clock search correlates, both sides on one grid.

Both sides of a signal go through the same low-pass filter (its width chosen from the mocap's
noise, :mod:`~mocap_calib.core.prepare.noise_band`) before the rotation-invariant norm is
taken:

- angular speed: the gyro's components and the mocap's body rates (central differences of the
  attitudes on the grid) smoothed, then ``|w|``. Gyro and mocap body rates differ by the
  constant ``R_MI``, so the filter keeps them related and the norm drops ``R_MI``.
- specific force: the accelerometer's components smoothed, then ``|f|``; the mocap's
  acceleration is the smoothed second derivative of its positions, then ``|a - g|`` for each
  axis-aligned up (the world's up axis is not known yet).

Smoothing the components before the norm keeps noise out of the norm (a rotor's vibration or a
noisy attitude would otherwise be rectified into a fluctuating floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import gap_threshold
from mocap_calib.core.prepare.noise_band import (
    Smoothing,
    choose_smoothing,
    imu_on_grid,
    mocap_gap,
    mocap_positions,
    mocap_rates,
    near_gap,
    smooth,
)

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Signal variation below which a signal cannot align anything.
MIN_SPEED_STD = 0.05  # rad/s
MIN_FORCE_STD = 0.3  # m/s^2
#: Axis-aligned candidates for the mocap world's up direction (gravity points down).
UP_AXES = {"+z": (2, 1.0), "-z": (2, -1.0), "+y": (1, 1.0), "-y": (1, -1.0), "+x": (0, 1.0),
           "-x": (0, -1.0)}


@dataclass(frozen=True)
class ClockSignal:
    """One signal on both sides, each on its grid ``start + k dt``: mean removed over the
    usable points (``*_ok``), zero elsewhere (gaps and ends the filter reaches)."""

    name: str
    start_i: float
    x: Array  # IMU side
    x_ok: Mask
    start_m: float
    y: Array  # mocap side
    y_ok: Mask


def _centred(z: Array, blank: Mask) -> Array:
    out = z - (z[~blank].mean() if np.any(~blank) else z.mean())
    out[blank] = 0.0
    return out


def signals(u: Array, gyro: Array, accel: Array, tau: Array, R_WM: Array, p_WM: Array,
            dt: float, gravity: float) -> tuple[list[ClockSignal], Smoothing]:
    """The angular speed and specific-force signals on both sides, smoothed as the mocap's
    noise needs (the widths are returned too)."""
    gap_i, gap_m = gap_threshold(u), mocap_gap(tau)
    g_i, a_i = imu_on_grid(u, gyro, dt, gap_i), imu_on_grid(u, accel, dt, gap_i)
    w_m = mocap_rates(tau, R_WM, dt, gap_m)
    pos = mocap_positions(tau, p_WM, dt, gap_m)
    sm = choose_smoothing(g_i, a_i, w_m, pos, tau, dt, gap_m)
    out = []
    x = np.linalg.norm(smooth(g_i.values, sm.rate_s, dt), axis=1)
    y = np.linalg.norm(smooth(w_m.values, sm.rate_s, dt), axis=1)
    if np.std(x) >= MIN_SPEED_STD and np.std(y) >= MIN_SPEED_STD:
        bx, by = near_gap(g_i.in_gap, sm.rate_s, dt), near_gap(w_m.in_gap, sm.rate_s, dt)
        out.append(ClockSignal("angular speed", g_i.start, _centred(x, bx), ~bx, w_m.start,
                               _centred(y, by), ~by))
    xf = np.linalg.norm(smooth(a_i.values, sm.force_s, dt), axis=1)
    if len(pos.values) > 8 * sm.force_s / dt and np.std(xf) >= MIN_FORCE_STD:
        acc = smooth(pos.values, sm.force_s, dt, order=2)
        near = near_gap(pos.in_gap, sm.force_s, dt)
        bx = near_gap(a_i.in_gap, sm.force_s, dt)
        xs = _centred(xf, bx)  # one array for every axis
        for axis_name, (i, sign) in UP_AXES.items():
            g = np.zeros(3)
            g[i] = -gravity * sign  # gravity points down the up axis
            f_m = _centred(np.linalg.norm(acc - g, axis=1), near)
            out.append(ClockSignal(f"specific force ({axis_name} up)", a_i.start, xs, ~bx,
                                   pos.start, f_m, ~near))
    return out, sm
