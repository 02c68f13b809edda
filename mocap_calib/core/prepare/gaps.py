"""IMU gaps by the one gap rule (:mod:`mocap_calib.core.policy`): found, trimmed at the log's
start, bridged or split, refused when they leave too little, and described for the log and
the result file (``imu_gaps:``).

Nothing is integrated across a gap: windows and keyframe intervals end at it
(:meth:`ImuGaps.spans_clear`), the bias random walk runs on over it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import (
    IMU_BRIDGE_MAX_S,
    IMU_MAX_GAP_FRACTION,
    IMU_TRIM_START_S,
    MIN_SEGMENT_S,
    gap_threshold,
)
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: IMU samples kept clear on each side of a gap: the cubic interpolant of a step reads the
#: samples next to it, which must be on the step's side of the gap.
EDGE_SAMPLES = 3


@dataclass(frozen=True)
class ImuGaps:
    """The gaps of one IMU stream (times in s on the stream's relative clock).

    Attributes:
        before: (G,) time of the last sample before each gap.
        after: (G,) time of the first sample after it.
        rows: (G,) index (in the stream as given, before trimming) of that first sample.
        threshold: the longest step that is not a gap (s).
        trimmed: samples dropped at the start (a gap at logger start).
        trimmed_s: how long the dropped start was.
        duration: the stream's span after trimming (s).
        margin: time kept clear on each side of a gap (s).
    """

    before: Array
    after: Array
    rows: IntArray
    threshold: float
    trimmed: int = 0
    trimmed_s: float = 0.0
    duration: float = 0.0
    margin: float = 0.0
    notes: tuple[str, ...] = field(default=())

    @property
    def count(self) -> int:
        return len(self.before)

    @property
    def lengths(self) -> Array:
        return self.after - self.before

    @property
    def split(self) -> NDArray[np.bool_]:
        """Gaps longer than the bridging limit: they split the session into segments."""
        return self.lengths > IMU_BRIDGE_MAX_S

    def spans(self, delta: float = 0.0) -> Array:
        """(G, 2) each gap's last sample before and first after it, moved by ``delta`` (mocap
        minus IMU time: on the mocap clock), for plots."""
        return np.stack([self.before, self.after], axis=1) + delta if self.count else \
            np.zeros((0, 2))

    def spans_clear(self, t0: Array, t1: Array) -> NDArray[np.bool_]:
        """Whether the spans ``[t0, t1]`` (IMU clock) stay clear of every gap (with the
        interpolant's margin)."""
        t0, t1 = np.asarray(t0, dtype=float), np.asarray(t1, dtype=float)
        if self.count == 0:
            return np.ones(np.broadcast(t0, t1).shape, bool)
        lo = self.before - self.margin
        hi = self.after + self.margin
        # A span overlaps gap g when t0 < hi_g and t1 > lo_g: find the first gap ending after
        # t0 and check that it starts after t1.
        k = np.searchsorted(hi, t0, side="right")
        k_c = np.minimum(k, self.count - 1)
        return (k >= self.count) | (t1 <= lo[k_c])

    def to_dict(self) -> dict[str, Any]:
        """The ``imu_gaps:`` block of a result file."""
        lengths = self.lengths
        split = self.split
        return {
            "count": self.count,
            "total_s": round(float(lengths.sum()), 4),
            "longest_s": round(float(lengths.max()), 4) if self.count else 0.0,
            "bridged": int((~split).sum()),
            "split": int(split.sum()),
            "segments": int(split.sum()) + 1,
            "trimmed_samples": self.trimmed,
            "trimmed_s": round(self.trimmed_s, 4),
            "gaps": [{"at_s": round(float(b), 4), "length_s": round(float(d), 4),
                      "row": int(r)} for b, d, r in zip(self.before, lengths, self.rows,
                                                        strict=True)][:50],
        }

    def summary(self) -> str:
        """One line for the log."""
        if self.count == 0 and not self.trimmed:
            return "IMU: no gaps"
        parts = []
        if self.trimmed:
            parts.append(f"{self.trimmed} samples ({self.trimmed_s:.3f} s) before a gap at the "
                         "log's start trimmed")
        if self.count:
            n_split = int(self.split.sum())
            what = (f"all bridged (up to {IMU_BRIDGE_MAX_S:g} s)" if n_split == 0 else
                    f"{self.count - n_split} bridged, {n_split} longer than "
                    f"{IMU_BRIDGE_MAX_S:g} s split the session into {n_split + 1} segments")
            parts.append(f"{self.count} gaps, longest {self.lengths.max():.3f} s, "
                         f"{self.lengths.sum():.3f} s in all: {what}")
        return "IMU gaps: " + "; ".join(parts)


def _steps_over(t: Array, threshold: float) -> IntArray:
    return np.flatnonzero(np.diff(t) > threshold)


def find_imu_gaps(t: Array, source: str = "IMU") -> tuple[int, ImuGaps]:
    """The gaps of IMU times ``t`` (s), by the gap rule.

    Returns:
        (samples to trim at the start, the gaps of the rest).

    Raises:
        ObservabilityError: the gaps cover most of the session, or leave no stretch long
            enough to use; the line names the first large gap's time and row and the fix.
    """
    threshold = gap_threshold(t)
    idx = _steps_over(t, threshold)
    trim = 0
    # Gaps within the first IMU_TRIM_START_S (logger start): trim what comes before them.
    early = idx[t[idx] - t[0] < IMU_TRIM_START_S]
    if len(early):
        trim = int(early[-1]) + 1
        idx = idx[idx >= trim]
    tt = t[trim:]
    before, after = t[idx], t[idx + 1]
    dt = float(np.median(np.diff(tt))) if len(tt) > 1 else 0.0
    gaps = ImuGaps(before, after, (idx + 1).astype(np.int64), threshold, trim,
                   float(t[trim] - t[0]) if trim else 0.0,
                   float(tt[-1] - tt[0]) if len(tt) else 0.0, EDGE_SAMPLES * dt)
    _refuse_unusable(gaps, tt, source)
    return trim, gaps


def _refuse_unusable(gaps: ImuGaps, t: Array, source: str) -> None:
    if gaps.count == 0 or len(t) < 2:
        return
    span = t[-1] - t[0]
    covered = float(gaps.lengths.sum())
    edges = np.r_[t[0], gaps.after]
    ends = np.r_[gaps.before, t[-1]]
    longest = float(np.max(ends - edges))
    worst = int(np.argmax(gaps.lengths))
    where = (f"the longest gap, {gaps.lengths[worst]:.3f} s, follows "
             f"{gaps.before[worst] - t[0]:.3f} s (data row {gaps.rows[worst] + 1})")
    if covered > IMU_MAX_GAP_FRACTION * span:
        raise ObservabilityError(
            f"{source}: gaps cover {covered:.1f} of the IMU log's {span:.1f} s ({gaps.count} "
            f"gaps; {where}); the log has too little data: re-record, or check the logger's "
            "buffer / the time column")
    if longest < MIN_SEGMENT_S:
        raise ObservabilityError(
            f"{source}: no stretch of the IMU log between gaps is {MIN_SEGMENT_S:g} s long "
            f"(the longest is {longest:.2f} s; {gaps.count} gaps, {where}); the log cannot "
            "carry a calibration: re-record, or check the time column")
