"""A session ready for calibration: both streams on their own relative clocks, checked.

Internally the IMU clock time ``u`` (seconds since the IMU origin) and the mocap clock time
``tau`` (seconds since the mocap origin) are related by ``tau = u + delta`` where
``delta = clock_shift + t_d`` and ``clock_shift = (origin_imu - origin_mocap) * 1e-9`` is exact
integer arithmetic. Working with ``delta`` keeps every float small even when the two clocks are
from different epochs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.jit import kernel
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.policy import MIN_SESSION_S, gap_threshold
from mocap_calib.core.prepare.fault_detection import (
    ImuFaults,
    frozen_mocap,
    imu_faults,
    refuse_dead,
)
from mocap_calib.core.prepare.gaps import ImuGaps, find_imu_gaps
from mocap_calib.core.prepare.noise_band import noise_band
from mocap_calib.core.prepare.pose_flips import refuse_flips
from mocap_calib.core.prepare.pose_screen import PoseScreen, screen_poses
from mocap_calib.core.prepare.pose_stream import arrived_together, describe_stream, stream_note
from mocap_calib.errors import InputError, ObservabilityError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PreparedSession:
    """Arrays the stages work on.

    Attributes:
        u: (N,) IMU times (s since the IMU origin).
        gyro, accel: (N, 3) raw IMU samples.
        tau: (M,) mocap times (s since the mocap origin).
        R_WM: (M, 3, 3) marker attitudes; p_WM: (M, 3) marker positions.
        clock_shift: ``(origin_imu - origin_mocap) * 1e-9``.
        gap: a mocap interval longer than this (s) is a gap.
        dropped_mocap_rows: rows removed on reading (occlusions).
    """

    u: Array
    gyro: Array
    accel: Array
    tau: Array
    R_WM: Array
    p_WM: Array
    clock_shift: float
    gap: float
    dropped_mocap_rows: int = 0
    spikes_removed: int = 0
    removed_tau: Array = field(default_factory=lambda: np.zeros(0))  # times of removed spikes
    imu_faults: ImuFaults | None = None  # saturated / frozen IMU samples (left out later)
    notes: tuple[str, ...] = ()  # what the sensor-fault screen removed
    imu_gaps: ImuGaps | None = None  # the IMU's gaps: nothing is integrated across them
    #: low-pass width (s, Gaussian sigma) the mocap's attitude noise needs for its body rates
    #: to be compared with the gyro (:func:`~mocap_calib.core.prepare.noise_band.noise_band`)
    band_s: float = 0.0

    def imu_clear(self, u0: Array, u1: Array) -> NDArray[np.bool_]:
        """Whether IMU-clock spans ``[u0, u1]`` hold no IMU gap (with the interpolant's
        margin)."""
        if self.imu_gaps is None:
            return np.ones(np.broadcast(u0, u1).shape, bool)
        return self.imu_gaps.spans_clear(u0, u1)

    @property
    def imu_rate(self) -> float:
        return float(1.0 / np.median(np.diff(self.u)))

    @property
    def mocap_rate(self) -> float:
        return float(1.0 / np.median(np.diff(self.tau)))

    def imu_covers(self, tau0: Array, tau1: Array, delta: float,
                   margin: int = 3) -> NDArray[np.bool_]:
        """Whether the IMU samples cover mocap-time spans ``[tau0, tau1]`` (with a margin)
        without a gap."""
        lo = self.u[margin] + delta
        hi = self.u[-1 - margin] + delta
        return (tau0 >= lo) & (tau1 <= hi) & self.imu_clear(tau0 - delta, tau1 - delta)

    def gap_cause(self) -> str:
        """Why the mocap has too many gaps, with the fix: for the refusals of too few
        gap-free intervals. Removed jumps (marker swaps) leave holes that are gaps."""
        n = self.spikes_removed
        if not n:
            return "the session is too short or the mocap has too many gaps"
        holes = int(np.sum(np.diff(self.tau) > self.gap))
        return (f"{n} mocap samples ({100.0 * n / (len(self.tau) + n):.1f} %) were removed as "
                f"implausible jumps (marker swaps or outliers), and the {holes} holes they and "
                "any dropouts leave are gaps; repair the marker labelling (swaps) in the mocap "
                "software and export again, or record a session without them")

    def segments_without_gaps(self, idx0: NDArray[np.int64],
                              idx1: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Whether mocap index ranges ``[idx0, idx1]`` contain no gap."""
        gaps = np.concatenate([[0], np.cumsum(np.diff(self.tau) > self.gap)])
        return gaps[idx1] == gaps[idx0]


def prepare(imu: ImuSamples, mocap: MocapPoses, min_duration: float = MIN_SESSION_S,
            noise: NoiseModel | None = None) -> PreparedSession:
    """Check that the two streams can support a calibration and put them on relative clocks.

    Gross mocap errors (see :func:`~mocap_calib.core.prepare.pose_screen.screen_poses`) are
    removed here; the jumps' count is in ``spikes_removed``. Poses stamped on arrival lose the
    earlier of each pair that arrived together and those delivered late (one note says so).

    Raises:
        InputError: too few samples, rates the method cannot use, a flipped marker set.
        ObservabilityError: session too short or static.
    """
    if len(imu) >= 100:  # (fewer: refused below)
        trim, gaps = find_imu_gaps(imu.t, imu.source)
        imu = imu.select(np.arange(len(imu)) >= trim) if trim else imu
    if len(imu) < 100:
        raise InputError(f"{imu.source}: only {len(imu)} IMU samples; a calibration needs at "
                         "least a few thousand (tens of seconds of motion)")
    if len(mocap) < 20:
        raise InputError(f"{mocap.source}: only {len(mocap)} mocap poses; a calibration needs "
                         "at least a few thousand (tens of seconds of motion)")
    dt_m = np.diff(mocap.t)
    dt_i = np.diff(imu.t)
    if np.any(dt_m <= 0) or np.any(dt_i <= 0):
        raise InputError("timestamps must increase strictly; sort the files and remove duplicates")
    if not _both_static(imu, mocap):  # both static: the static session is the message
        refuse_dead(imu, mocap)
    notes: list[str] = [gaps.summary()] if gaps.count or gaps.trimmed else []
    frozen = frozen_mocap(mocap)
    if frozen.any():
        notes.append(f"{int(frozen.sum())} mocap samples ({frozen.sum() / mocap.rate_hz:.2f} s) "
                     "were frozen (the same pose repeated) and were left out")
        mocap = mocap.select(~frozen)
    duration = min(imu.duration, mocap.duration)
    if duration < min_duration:
        raise ObservabilityError(
            f"the session is only {duration:.1f} s long; record at least {min_duration:.0f} s "
            "(better 60-120 s) of motion that rotates the body about all axes")
    gyro_speed = np.linalg.norm(imu.gyro - np.median(imu.gyro, axis=0), axis=1)
    p_range = np.ptp(mocap.position, axis=0)
    R = mocap.rotation
    angles = np.linalg.norm(so3.log(np.einsum("ji,njk->nik", R[0], R)), axis=1)
    if np.percentile(gyro_speed, 90) < 0.1 or (np.max(angles) < np.radians(10)
                                               and np.max(p_range) < 0.05):
        raise ObservabilityError(
            "the session is (nearly) static: the body rotates less than 10 deg or the gyro "
            "barely moves; calibration needs motion that rotates the body about all axes")
    gap = gap_threshold(mocap.t, 0.02)
    mocap, screen, note = _screen_poses(mocap, gap, noise or NoiseModel())
    notes += [note] if note else []
    bad = screen.jumps | screen.late
    keep = ~bad
    R = mocap.rotation
    refuse_flips(mocap.t[keep], R[keep], mocap.source)
    band = noise_band(imu.t, imu.gyro, imu.accel, mocap.t[keep], R[keep], mocap.position[keep])
    return PreparedSession(
        u=imu.t, gyro=imu.gyro, accel=imu.accel, tau=mocap.t[keep], R_WM=R[keep],
        p_WM=mocap.position[keep],
        clock_shift=(imu.time_origin_ns - mocap.time_origin_ns) * 1e-9,
        gap=gap,
        dropped_mocap_rows=mocap.dropped_rows,
        spikes_removed=int(screen.jumps.sum()),
        removed_tau=mocap.t[screen.jumps],
        imu_faults=imu_faults(imu.gyro, imu.accel, imu.rate_hz),
        notes=tuple(notes),
        imu_gaps=gaps,
        band_s=band.rate_s,
    )


def _screen_poses(mocap: MocapPoses, gap: float, nz: NoiseModel
                  ) -> tuple[MocapPoses, PoseScreen, str | None]:
    """The stream described, the earlier of poses that arrived together left out, and the
    gross errors found (see :func:`~mocap_calib.core.prepare.pose_screen.screen_poses`)."""
    stream = describe_stream(mocap.t, mocap.quat_wxyz, mocap.position)
    together = np.zeros(len(mocap), bool)
    if stream.arrival_stamped:
        together = arrived_together(mocap.t, stream.near_step_s)
        mocap = mocap.select(~together)
    screen = screen_poses(mocap.t, mocap.rotation, mocap.position, gap,
                          nz.mocap_position_sigma, nz.mocap_rotation_sigma,
                          stream.arrival_stamped)
    note = stream_note(stream, int(together.sum()), int(screen.late.sum()),
                       screen.late_s[screen.late], screen.sigma_position_m,
                       screen.sigma_rotation_rad)
    return mocap, screen, note


def _both_static(imu: ImuSamples, mocap: MocapPoses) -> bool:
    speed = np.linalg.norm(imu.gyro - np.median(imu.gyro, axis=0), axis=1)
    R = mocap.rotation
    angles = np.linalg.norm(so3.log(np.einsum("ji,njk->nik", R[0], R)), axis=1)
    return bool(np.percentile(speed, 90) < 0.1 and np.max(angles) < np.radians(10)
                and np.max(np.ptp(mocap.position, axis=0)) < 0.05)


def local_derivative(t: Array, y: Array, half: int,
                     gap: float) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Smoothed value and first derivative of ``y(t)`` by a local quadratic fit.

    Args:
        t: (M,) times; y: (M, d) values.
        half: samples on each side of the fit window.
        gap: a spacing above this marks the fit invalid (windows do not span gaps).

    Returns:
        value (M, d), derivative (M, d), valid (M,).
    """
    t = np.ascontiguousarray(t, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    seg = np.concatenate([[0], np.cumsum(np.diff(t) > gap)]).astype(np.int64)
    value, deriv = np.zeros_like(y), np.zeros_like(y)
    valid = np.zeros(len(t), dtype=np.bool_)
    _local_quadratic(t, y, int(half), seg, value, deriv, valid)
    return value, deriv, valid


@kernel
def _local_quadratic(t, y, half, seg, value, deriv, valid):  # pragma: no cover  (compiled)
    """Per sample, least squares of ``y = a + b dt + c dt^2`` over the samples within
    ``half`` of it (indices clipped at the ends; a fit at the ends or across a gap is marked
    invalid and solved with identity normal equations)."""
    M, d = y.shape
    A = np.zeros((3, 3))
    B = np.zeros((3, d))
    for m in range(M):
        lo, hi = m - half, m + half
        ok = lo >= 0 and hi < M
        if ok:
            ok = seg[hi] == seg[lo]
        valid[m] = ok
        A[:, :] = 0.0
        B[:, :] = 0.0
        for k in range(lo, hi + 1):
            kk = min(max(k, 0), M - 1)
            dt = t[kk] - t[m]
            v0, v1, v2 = 1.0, dt, dt * dt
            A[0, 0] += v0 * v0
            A[0, 1] += v0 * v1
            A[0, 2] += v0 * v2
            A[1, 1] += v1 * v1
            A[1, 2] += v1 * v2
            A[2, 2] += v2 * v2
            for c in range(d):
                yk = y[kk, c]
                B[0, c] += v0 * yk
                B[1, c] += v1 * yk
                B[2, c] += v2 * yk
        A[1, 0], A[2, 0], A[2, 1] = A[0, 1], A[0, 2], A[1, 2]
        if not ok:
            A[:, :] = 0.0
            for i in range(3):
                A[i, i] = 1.0
        _solve3(A, B, value[m], deriv[m])


@kernel
def _solve3(A, B, x0_out, x1_out):  # pragma: no cover  (compiled)
    """``A X = B`` (3 x 3, columns of ``B``) by Gaussian elimination with partial pivoting;
    rows 0 and 1 of ``X`` into ``x0_out`` and ``x1_out`` (``A`` and ``B`` are overwritten)."""
    d = B.shape[1]
    for col in range(3):
        piv = col
        for r in range(col + 1, 3):
            if abs(A[r, col]) > abs(A[piv, col]):
                piv = r
        if piv != col:
            for j in range(3):
                A[col, j], A[piv, j] = A[piv, j], A[col, j]
            for c in range(d):
                B[col, c], B[piv, c] = B[piv, c], B[col, c]
        for r in range(col + 1, 3):
            f = A[r, col] / A[col, col]
            for j in range(col, 3):
                A[r, j] -= f * A[col, j]
            for c in range(d):
                B[r, c] -= f * B[col, c]
    for c in range(d):
        x2 = B[2, c] / A[2, 2]
        x1 = (B[1, c] - A[1, 2] * x2) / A[1, 1]
        x0_out[c] = (B[0, c] - A[0, 1] * x1 - A[0, 2] * x2) / A[0, 0]
        x1_out[c] = x1
