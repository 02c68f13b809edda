"""The mocap's gross errors, judged by each pose's deviation from a local fit of its neighbours.

Every pose is compared with the quadratic fitted (least squares, in time) to the poses around
it, itself left out: position in metres, attitude as the rotation between the fit and the
pose. A marker swap or a mis-solved frame moves the pose by centimetres or degrees for one to a
few frames, far outside the fit; the mocap's noise, quantisation and (for poses stamped on
arrival) the stamps' scatter move it by a fraction of that. The fit spans a time, not a pair
of samples, so poses a few microseconds apart (two that arrived together) do not turn their
noise into huge rates as finite differences do.

Thresholds: a deviation beyond :data:`NOISE_FACTOR` times the data's own robust noise level
(normalised for the fit's own uncertainty) and beyond the floors :data:`FLOOR_POSITION_M` /
:data:`FLOOR_ROTATION_RAD` is a jump. Fits are repeated without the poses found (a swap of
several frames spoils its neighbours' first fits) until nothing changes (at most
:data:`MAX_PASSES` times).

For poses stamped on arrival, a pose that reached the receiver late (after a radio gap) lies
behind the motion along the velocity and angular rate at once; a deviation that one time shift
explains (a capture before the stamp, no earlier than the steps around the pose allow) is a
late pose, not a swap.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.threads import map_blocks

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Neighbours on each side of a pose in its fit: at least this many ...
MIN_HALF = 4
#: ... and enough to span this time (s).
FIT_SPAN_S = 0.015
#: Poses stamped on arrival: fits span holes up to this long (s), so that a pose delivered
#: late after a radio dropout is compared with the motion on both sides of the hole.
ARRIVAL_FIT_HOLE_S = 0.1
#: A jump deviates this many robust noise sigmas from the fit of its neighbours ...
NOISE_FACTOR = 12.0
#: ... and at least this much (a marker swap moves a pose by centimetres and degrees).
FLOOR_POSITION_M = 0.01
FLOOR_ROTATION_RAD = float(np.radians(3.0))
#: A fit needs at least this many neighbours (a quadratic and a check of it).
MIN_NEIGHBOURS = 5
MAX_PASSES = 5
#: Poses whose neighbours' relative rotations are taken at once: the logarithm's temporaries
#: take ~400 bytes per pose and neighbour (80 MB for a minute at 300 Hz in one go).
_CHUNK_ROWS = 4096


@dataclass(frozen=True)
class Deviations:
    """Each pose against the quadratic fitted to its neighbours (itself left out).

    Attributes:
        dp: (M, 3) position minus the fit (m); dr: (M, 3) rotation vector from the fit's
            attitude to the pose's, in the pose's frame (rad).
        v: (M, 3) the fit's velocity (m/s); w: (M, 3) its body rate (rad/s).
        spread: (M,) ``sqrt(1 + leverage)``: the deviation's noise in units of the pose noise
            (the fit's own error adds to the pose's).
        valid: (M,) the fit had enough neighbours.
    """

    dp: Array
    dr: Array
    v: Array
    w: Array
    spread: Array
    valid: Mask


def fit_half_width(t: Array) -> int:
    """Neighbours on each side of a pose in its fit."""
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return max(MIN_HALF, int(np.ceil(FIT_SPAN_S / max(step, 1e-9))))


class Neighbourhoods:
    """Every pose's neighbours (``half`` on each side, not across gaps) in the local
    coordinates of the fits: time in typical steps, position and rotation vector relative to
    the pose. Computed once; fits with other choices of usable poses reuse them."""

    def __init__(self, t: Array, R: Array, p: Array, gap: float, half: int,
                 rows: NDArray[np.int64] | None = None):
        M = len(t)
        self.rows = np.arange(M) if rows is None else rows
        offs = np.array([k for k in range(-half, half + 1) if k != 0])
        raw = self.rows[:, None] + offs[None, :]
        self.idx = np.clip(raw, 0, M - 1)
        seg = np.concatenate([[0], np.cumsum(np.diff(t) > gap)])
        self.inside = (raw >= 0) & (raw < M) & (seg[self.idx] == seg[self.rows, None])
        self.step = float(np.median(np.diff(t))) if M > 1 else 1.0
        self.x = (t[self.idx] - t[self.rows, None]) / self.step  # well-conditioned fits
        self.yp = p[self.idx] - p[self.rows, None, :]
        self.yr = np.empty(self.yp.shape)

        def logs(a: int) -> None:  # a block of rows (bounded temporaries), on the threads
            b = a + _CHUNK_ROWS
            Rt = np.transpose(R[self.rows[a:b]], (0, 2, 1))
            self.yr[a:b] = so3.log(np.einsum("mij,mnjk->mnik", Rt, R[self.idx[a:b]])
                                   .reshape(-1, 3, 3)).reshape(len(Rt), len(offs), 3)

        map_blocks(logs, range(0, len(self.rows), _CHUNK_ROWS))

    def fit(self, use: Mask) -> Deviations:
        """Leave-one-out quadratic fits (see :class:`Deviations`) from the neighbours in
        ``use`` (row blocks on the threads)."""
        parts = map_blocks(lambda a: self._fit(use, slice(a, a + _CHUNK_ROWS)),
                           range(0, max(len(self.rows), 1), _CHUNK_ROWS))
        return Deviations(*(np.concatenate([getattr(d, f.name) for d in parts])
                            for f in fields(Deviations)))

    def _fit(self, use: Mask, rows: slice) -> Deviations:
        """The fits of the rows ``rows``."""
        wt = (self.inside[rows] & use[self.idx[rows]]).astype(float)
        x = self.x[rows]
        V = np.stack([np.ones_like(x), x, x * x], axis=2)  # (M, n, 3)
        Vt = np.transpose(V * wt[..., None], (0, 2, 1))  # weights 0 or 1
        N = Vt @ V
        valid = wt.sum(axis=1) >= MIN_NEIGHBOURS  # (one-sided near ends and gaps)
        N[~valid] = np.eye(3)
        Ninv = np.linalg.inv(N)
        cp = Ninv @ (Vt @ self.yp[rows])
        cr = Ninv @ (Vt @ self.yr[rows])
        out = [-cp[:, 0, :], -cr[:, 0, :], cp[:, 1, :] / self.step, cr[:, 1, :] / self.step]
        for a in out:
            a[~valid] = 0.0
        spread = np.sqrt(1.0 + np.where(valid, Ninv[:, 0, 0], 0.0))
        return Deviations(*out, spread, valid)


def robust_sigma(d: Array, spread: Array, valid: Mask) -> float:
    """Per-axis noise sigma of deviations ``d`` (M, 3) normalised by ``spread`` (MAD)."""
    z = (d[valid] / spread[valid, None]).ravel()
    return float(1.4826 * np.median(np.abs(z))) if len(z) else 0.0


@dataclass(frozen=True)
class PoseScreen:
    """What :func:`screen_poses` found.

    Attributes:
        jumps: (M,) poses far from the fit of their neighbours that no time shift explains
            (marker swaps, mis-solved frames).
        late: (M,) poses of an arrival-stamped stream that lie behind (or ahead of) the motion
            by one time shift (they reached the receiver late).
        late_s: (M,) the time shift of each (s; positive: captured before its stamp).
        sigma_position_m, sigma_rotation_rad: the robust per-axis noise of the poses about the
            local fits (quantisation, noise and the stamps' scatter together), as the data
            show it (the thresholds use at least the assumed noise).
        position_threshold_m, rotation_threshold_rad: the thresholds used (for a typical
            fit).
    """

    jumps: Mask
    late: Mask
    late_s: Array
    sigma_position_m: float
    sigma_rotation_rad: float
    position_threshold_m: float
    rotation_threshold_rad: float


def screen_poses(t: Array, R: Array, p: Array, gap: float, sigma_p: float, sigma_r: float,
                 arrival_stamped: bool = False) -> PoseScreen:
    """Find jumps (and, for arrival-stamped poses, late poses) among the poses.

    Args:
        t, R, p: the poses (s, rotation matrices, m).
        gap: longest step (s) that is not a gap.
        sigma_p, sigma_r: the noise the user assumes (m, rad per axis); the thresholds are
            at least :data:`NOISE_FACTOR` times these too.
        arrival_stamped: the stamps are arrival times: deviations one time shift explains
            are late poses.
    """
    M = len(t)
    none = np.zeros(M, bool)
    if M < 2 * MIN_NEIGHBOURS:
        return PoseScreen(none, none, np.zeros(M), 0.0, 0.0, FLOOR_POSITION_M,
                          FLOOR_ROTATION_RAD)
    half = fit_half_width(t)
    if arrival_stamped:
        gap = max(gap, ARRIVAL_FIT_HOLE_S)
    near = Neighbourhoods(t, R, p, gap, half)
    flagged = none.copy()
    for _ in range(MAX_PASSES):
        d = near.fit(~flagged)
        if not np.all(d.valid):  # poses amid a run of flagged ones: wider fits
            rows = np.flatnonzero(~d.valid)
            d = _merged(d, rows, Neighbourhoods(t, R, p, gap, 3 * half, rows).fit(~flagged))
        ok = d.valid & ~flagged
        own_p, own_r = robust_sigma(d.dp, d.spread, ok), robust_sigma(d.dr, d.spread, ok)
        s_p, s_r = max(own_p, sigma_p), max(own_r, sigma_r)
        thr_p = np.maximum(FLOOR_POSITION_M, NOISE_FACTOR * s_p * d.spread)
        thr_r = np.maximum(FLOOR_ROTATION_RAD, NOISE_FACTOR * s_r * d.spread)
        shift = _time_shift(t, d, s_p, s_r) if arrival_stamped else np.zeros(M)
        off = _beyond(d.dp, d.dr, thr_p, thr_r)
        rest = _beyond(d.dp + d.v * shift[:, None], d.dr + d.w * shift[:, None], thr_p,
                       thr_r)
        # Late: explained by a capture before the stamp (arrival stamps are never early).
        # A pose whose fit cannot be judged keeps its verdict.
        explained = off & ~rest & (shift > 0)
        jumps = np.where(d.valid, off & ~explained, flagged)
        late = d.valid & explained
        now = jumps | late
        if np.array_equal(now, flagged):
            break
        flagged = now
    typical = float(np.median(d.spread[d.valid])) if np.any(d.valid) else 1.0
    return PoseScreen(jumps, late, np.where(late, shift, 0.0), own_p, own_r,
                      max(FLOOR_POSITION_M, NOISE_FACTOR * s_p * typical),
                      max(FLOOR_ROTATION_RAD, NOISE_FACTOR * s_r * typical))


def _merged(near: Deviations, rows: NDArray[np.int64], wide: Deviations) -> Deviations:
    """The near fits with those of ``rows`` replaced by the wide ones."""
    out = [a.copy() for a in (near.dp, near.dr, near.v, near.w, near.spread, near.valid)]
    for a, b in zip(out, (wide.dp, wide.dr, wide.v, wide.w, wide.spread, wide.valid),
                    strict=True):
        a[rows] = b
    return Deviations(*out)


def _beyond(dp: Array, dr: Array, thr_p: Array, thr_r: Array) -> Mask:
    return (np.linalg.norm(dp, axis=1) > thr_p) | (np.linalg.norm(dr, axis=1) > thr_r)


def _time_shift(t: Array, d: Deviations, s_p: float, s_r: float) -> Array:
    """Per pose, the time shift (s) that best explains its deviation as the motion seen
    earlier (positive) or later: ``dev ~ -rate * shift`` for position and attitude at once,
    weighted by their noise; no larger than the longer step beside the pose plus two typical
    steps (a pose captured before its predecessor would arrive out of order)."""
    wp, wr = 1.0 / max(s_p, 1e-12) ** 2, 1.0 / max(s_r, 1e-12) ** 2
    info = wp * np.sum(d.v * d.v, axis=1) + wr * np.sum(d.w * d.w, axis=1)
    score = wp * np.sum(d.v * d.dp, axis=1) + wr * np.sum(d.w * d.dr, axis=1)
    shift = -score / np.maximum(info, 1e-300)
    dt = np.diff(t)
    step = float(np.median(dt))
    longest = np.maximum(np.concatenate([[dt[0]], dt]), np.concatenate([dt, [dt[-1]]]))
    bound = longest + 2.0 * step
    return np.where(info > 0, np.clip(shift, -bound, bound), 0.0)
