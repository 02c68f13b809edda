"""What kind of pose stream the mocap is: stamped at capture or on arrival, quantised or not.

A motion-capture system stamps its frames at a fixed rate. Poses relayed to a vehicle (e.g. a
Crazyflie's external pose, sent over the radio) are often stamped when they arrive instead:
the steps between stamps scatter widely around the frame period, some poses arrive together
(microseconds apart, the older one delivered late) and a pose delivered after a radio dropout
is older than its stamp. Relayed poses are also compressed: positions rounded to a grid
(1 mm), quaternions packed into a few bits per component. None of this is a marker swap; the
screen (:mod:`~mocap_calib.core.prepare.pose_screen`) and the clock search treat it as noise,
and the user is told what the stream is, with its sizes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Steps whose 5-95 % range exceeds this fraction of the median step: stamped on arrival (a
#: capture clock's steps scatter by a few percent at most).
ARRIVAL_SPREAD = 0.5
#: A step shorter than this fraction of the median: two poses that arrived together.
NEAR_FRACTION = 0.03
#: Values on a grid: this fraction of them within :data:`GRID_TOLERANCE` steps of it.
ON_GRID = 0.95
GRID_TOLERANCE = 0.05
#: Coarsest quanta that count (m, and quaternion units): finer is float rounding.
MIN_POSITION_QUANTUM_M = 1e-5
MIN_QUATERNION_QUANTUM = 1e-5


@dataclass(frozen=True)
class PoseStream:
    """How the mocap's poses were stamped and stored.

    Attributes:
        step_quantiles_s: the 5, 50 and 95 % quantiles of the steps between stamps (s).
        near_fraction: fraction of steps shorter than :data:`NEAR_FRACTION` of the median.
        arrival_stamped: the steps scatter as arrival times do (see :data:`ARRIVAL_SPREAD`).
        position_quantum_m: the grid the positions lie on (None: not quantised).
        attitude_quantum_rad: the rotation one step of the quaternion grid makes (None: not
            quantised).
    """

    step_quantiles_s: tuple[float, float, float]
    near_fraction: float
    arrival_stamped: bool
    position_quantum_m: float | None
    attitude_quantum_rad: float | None

    @property
    def near_step_s(self) -> float:
        return NEAR_FRACTION * self.step_quantiles_s[1]

    @property
    def quantised(self) -> bool:
        return self.position_quantum_m is not None or self.attitude_quantum_rad is not None


def describe_stream(t: Array, quat_wxyz: Array, p: Array) -> PoseStream:
    """The stream's stamps and quantisation (see :class:`PoseStream`)."""
    dt = np.diff(t)
    q05, q50, q95 = (float(x) for x in np.percentile(dt, [5, 50, 95]))
    arrival = q50 > 0 and (q95 - q05) > ARRIVAL_SPREAD * q50
    near = float(np.mean(dt < NEAR_FRACTION * q50)) if q50 > 0 else 0.0
    pq = grid_step(p.ravel(), MIN_POSITION_QUANTUM_M)
    small = np.sort(np.abs(quat_wxyz), axis=1)[:, :3].ravel()
    qq = grid_step(small, MIN_QUATERNION_QUANTUM)
    # One quaternion step q in a small component turns the body by about 2 q rad.
    return PoseStream((q05, q50, q95), near, bool(arrival), pq,
                      None if qq is None else 2.0 * qq)


def grid_step(x: Array, smallest: float) -> float | None:
    """The step of the grid the values ``x`` lie on, or None (no grid as coarse as
    ``smallest``). The step is estimated from the smallest gaps between distinct values and
    refined by least squares over every value."""
    x = x[np.isfinite(x)]
    d = np.diff(np.unique(x))
    # Gaps below a millionth of the values' size are float rounding (renormalised
    # quaternions, float32 files), not a step of a grid.
    d = d[d > 1e-6 * float(np.max(np.abs(x), initial=0.0))]
    if len(d) < 10:
        return None
    # Candidate steps: the gaps' quantiles, smallest first (a few values off the grid leave
    # small gaps of their own); the first that the values lie on is the step.
    for cand in np.percentile(d, [1, 5, 10, 25, 50]):
        k = np.round(d / cand)
        ones = d[k == 1]
        q = float(np.median(ones)) if len(ones) else float(cand)
        if q >= smallest and _on_grid(x, q):
            return _refined(x, q)
    return None


def _refined(x: Array, q: float) -> float:
    """Least squares of ``x = n q`` with ``n`` the nearest integers (twice)."""
    for _ in range(2):
        n = np.round(x / q)
        nn = float(n @ n)
        if nn == 0:
            break
        q = float(n @ x) / nn
    return q


def _on_grid(x: Array, q: float) -> bool:
    r = _refined(x, q)
    return float(np.mean(np.abs(x / r - np.round(x / r)) < GRID_TOLERANCE)) >= ON_GRID


def arrived_together(t: Array, near_step_s: float) -> Mask:
    """The earlier pose of each pair stamped less than ``near_step_s`` apart.

    Two poses that reach the receiver together were captured a frame or more apart; the
    earlier one waited longer, so its stamp is further from its capture (on the Crazyflie
    flights of the UTIL dataset the earlier lies about 2.5 ms behind the motion, the later
    about 1 ms ahead, against 0.2 ms for the others). It is left out: the later one stays."""
    out = np.zeros(len(t), bool)
    out[:-1] = np.diff(t) < near_step_s
    return out


def stream_note(stream: PoseStream, left_together: int, late: int, late_s: Array,
                sigma_position_m: float, sigma_rotation_rad: float) -> str | None:
    """One line for the user on an arrival-stamped or quantised stream (None for a stream
    stamped at capture and not quantised)."""
    if not (stream.arrival_stamped or stream.quantised):
        return None
    parts = []
    if stream.arrival_stamped:
        q05, q50, q95 = (1e3 * x for x in stream.step_quantiles_s)
        text = (f"poses stamped on arrival: steps {q05:.1f}-{q95:.1f} ms (5-95 %) around "
                f"{q50:.1f} ms, {100 * stream.near_fraction:.2f} % within "
                f"{1e3 * stream.near_step_s:.1f} ms of the previous")
        if left_together:
            text += f" (the earlier of each such pair, {left_together} poses, left out)"
        parts.append(text)
        if late:
            ms = np.round(1e3 * np.abs(late_s))
            span = f"{ms.min():.0f}" + (f"-{ms.max():.0f}" if ms.max() > ms.min() else "")
            parts.append(f"{late} poses delivered {span} ms late (behind the motion by that "
                         "time) left out")
    if stream.position_quantum_m is not None:
        parts.append(f"positions quantised to {_length(stream.position_quantum_m)}")
    if stream.attitude_quantum_rad is not None:
        parts.append(f"attitudes quantised to {np.degrees(stream.attitude_quantum_rad):.2g} "
                     "deg")
    parts.append(f"scatter about the motion {1e3 * sigma_position_m:.2g} mm and "
                 f"{np.degrees(sigma_rotation_rad):.2g} deg per axis: treated as mocap noise, "
                 "not marker swaps")
    return "; ".join(parts)


def _length(metres: float) -> str:
    return f"{metres * 1e3:.3g} mm" if metres < 0.01 else f"{metres * 100:.3g} cm"
