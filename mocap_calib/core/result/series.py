"""The series the outputs draw, computed once after the fit and handed to every writer as data.

A calibration's outputs (the rerun recording, the HTML report) show more than the result file:
the IMU predicted from the mocap against what it measured, the residual analysis with its noise
floor and spectra, IMU dead reckoning from the mocap state, each take's mocap and IMU gaps, the
solver's iterates and the clock search's curve. :class:`OutputSeries` holds them, typed and
immutable; ``core/diagnosis/outputs.py`` builds it from a result and its diagnostics, computing
only what the requested outputs draw. The writers (``viz``, ``report``) read it and the result,
and call nothing of the estimator.

Times are mocap times in seconds since the mocap origin (``tau``), unless a field says IMU time
(``u``, seconds since the IMU origin; ``tau = u + delta``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.stages.figures import ResidualSeries

Array = NDArray[np.float64]

__all__ = ["ClockCurve", "DeadReckoning", "ImuPrediction", "OutputSeries", "ReportFigures",
           "ResidualAnalysis", "ResidualSeries", "Scene", "SolverHistory", "StageSpectrum",
           "TakeSeries"]


@dataclass(frozen=True)
class ImuPrediction:
    """Measured and predicted IMU samples where the mocap supports a prediction.

    Attributes:
        u: (n,) IMU times (s since the IMU origin) of the compared samples.
        segments: list of index arrays into ``u``: gap-free stretches.
        gyro_meas, accel_meas: (n, 3) measured.
        gyro_pred, accel_pred: (n, 3) predicted through the calibrated model.
        w, f: (n, 3) true rate and specific force derived from the mocap.
    """

    u: Array
    segments: list[NDArray[np.int64]]
    gyro_meas: Array
    accel_meas: Array
    gyro_pred: Array
    accel_pred: Array
    w: Array
    f: Array


@dataclass(frozen=True)
class ResidualAnalysis:
    """Measured minus predicted, in time (low-passed) and frequency, with the noise floor.

    Attributes:
        cutoff_hz: low-pass cutoff of the time-domain comparison.
        gyro_rms, accel_rms: (3,) RMS of the low-passed residual per axis.
        gyro_floor, accel_floor: (3,) what noise alone gives through the same processing.
        freq: (F,) Welch frequencies; gyro_psd, accel_psd: (F, 3) residual PSDs;
        gyro_psd_floor, accel_psd_floor: (F, 3) PSD of the noise-only residual.
        gyro_lp, accel_lp: (n, 3) low-passed residual series (for plots).
        floor_parts: floor per source (white noise, bias walk, mocap), gyro then accel axes.
        t: (n,) mocap-clock times of the series; keep: (n,) samples the RMS uses (away
            from segment ends).
    """

    cutoff_hz: float
    gyro_rms: Array
    accel_rms: Array
    gyro_floor: Array
    accel_floor: Array
    freq: Array
    gyro_psd: Array
    accel_psd: Array
    gyro_psd_floor: Array
    accel_psd_floor: Array
    gyro_lp: Array = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    accel_lp: Array = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    floor_parts: dict[str, Array] = field(default_factory=dict)
    t: Array = field(repr=False, default_factory=lambda: np.zeros(0))  # mocap-clock times
    keep: NDArray[np.bool_] = field(repr=False, default_factory=lambda: np.zeros(0, bool))

    def to_dict(self) -> dict[str, object]:
        return {"cutoff_hz": self.cutoff_hz,
                "gyro_rms": self.gyro_rms.tolist(), "gyro_floor": self.gyro_floor.tolist(),
                "accel_rms": self.accel_rms.tolist(), "accel_floor": self.accel_floor.tolist(),
                "bands": self.band_ratios()}

    def band_ratios(self, edges: tuple[float, ...] = (0.0, 0.5, 2.0, 5.0, 10.0, 20.0, 50.0),
                    ) -> dict[str, object]:
        """Residual over noise-floor power per frequency band, per sensor and axis (Welch)."""
        out: dict[str, object] = {}
        for sensor, psd, floor in (("gyro", self.gyro_psd, self.gyro_psd_floor),
                                   ("accel", self.accel_psd, self.accel_psd_floor)):
            rows = {}
            for lo, hi in zip(edges[:-1], edges[1:], strict=True):
                sel = (self.freq > lo) & (self.freq <= hi)
                if not np.any(sel):
                    continue
                ratio = psd[sel].sum(axis=0) / np.maximum(floor[sel].sum(axis=0), 1e-300)
                rows[f"{lo:g}-{hi:g} Hz"] = [round(float(x), 3) for x in ratio]
            out[sensor] = rows
        return out


@dataclass(frozen=True)
class DeadReckoning:
    """IMU dead-reckoning segments started from the mocap state.

    Attributes:
        tau: (S, m+1) mocap times of the segment samples.
        R_ref, p_ref: (S, m+1, 3, 3), (S, m+1, 3) IMU pose from the mocap (``T_WM T_MI``).
        R_before, p_before: integrated from the raw IMU (zero biases, no effects).
        R_after, p_after: integrated through the calibrated model (knot biases, effects).
        length_s: the segments' length (s).
    """

    tau: Array
    R_ref: Array
    p_ref: Array
    R_before: Array
    p_before: Array
    R_after: Array
    p_after: Array
    length_s: float

    def position_error(self, which: str) -> Array:
        """(S,) position error at the segment ends (m), ``which`` = before / after."""
        p = self.p_before if which == "before" else self.p_after
        return np.linalg.norm(p[:, -1] - self.p_ref[:, -1], axis=1)

    def attitude_error(self, which: str) -> Array:
        """(S,) attitude error at the segment ends (deg)."""
        R = self.R_before if which == "before" else self.R_after
        return so3.angle_deg(np.einsum("sji,sjk->sik", R[:, -1], self.R_ref[:, -1]))


@dataclass(frozen=True)
class StageSpectrum:
    """Welch PSD of one stage's residuals (per axis) and the white floor its noise model
    assumes (per axis, in the residual's unit^2/Hz)."""

    unit: str
    freq: Array
    before: Array
    after: Array
    floor: Array


@dataclass(frozen=True)
class ClockCurve:
    """The coarse clock search's correlation statistic against ``t_d``.

    Attributes:
        lags, score: (n,) ``t_d`` (s) and the combined statistic there (null sigmas).
        time_offset: the chosen peak's ``t_d`` (s); peak_z, margin_z: its height and lead.
        candidates: (t_d, z) of the highest peaks, best first.
        min_peak_z: the height a peak needs to be resolved.
    """

    lags: Array
    score: Array
    time_offset: float
    candidates: tuple[tuple[float, float], ...]
    peak_z: float
    margin_z: float
    min_peak_z: float


@dataclass(frozen=True)
class SolverHistory:
    """The position stage's iterates, one row per iteration.

    Attributes:
        iteration: (n,) iteration numbers; cost: (n,) LM error.
        delta: (n,) mocap minus IMU time (s); clock_shift: its part from the clocks' origins
            (``delta - clock_shift`` is the time offset).
        g_dir: (n, 3) gravity direction; p_MI: (n, 3); R_MI: (n, 3, 3).
        gyro_bias, accel_bias: (n, 3) session-mean biases.
    """

    iteration: NDArray[np.int64]
    cost: Array
    delta: Array
    g_dir: Array
    p_MI: Array
    R_MI: Array
    gyro_bias: Array
    accel_bias: Array
    clock_shift: float


@dataclass(frozen=True)
class Scene:
    """One take's mocap poses, gaps and calibrated frames.

    Attributes:
        tau: (M,) mocap times; R_WM: (M, 3, 3); p_WM: (M, 3) marker poses.
        mocap_rate, imu_rate: the sessions' median rates (Hz).
        gap: a mocap interval longer than this (s) is a gap; gap_index: (g,) the samples a gap
            follows (``tau[i]`` to ``tau[i + 1]``).
        removed_tau: (r,) times of the removed mocap spikes; removed_p_WM: (r, 3) the marker
            path there (interpolated).
        imu_gaps: (G, 2) each IMU gap's last sample before and first after it (mocap time).
        R_MI, p_MI: the IMU in the marker frame; g_W: gravity in the mocap world (m/s^2);
        delta: mocap minus IMU time (s).
        from_solver: the session and state the solver used; False: the session prepared
            again from the inputs with the result's values (constant biases).
    """

    tau: Array
    R_WM: Array
    p_WM: Array
    mocap_rate: float
    imu_rate: float
    gap: float
    gap_index: NDArray[np.int64]
    removed_tau: Array
    removed_p_WM: Array
    imu_gaps: Array
    R_MI: Array
    p_MI: Array
    g_W: Array
    delta: float
    from_solver: bool = True


@dataclass(frozen=True)
class ReportFigures:
    """What the HTML report shows of a take beyond the residual series.

    Attributes:
        stage_spectra: per stage name.
        imu_analysis: measured-minus-predicted IMU residuals with the Monte Carlo noise floor.
        imu_before: (freq, gyro, accel) PSDs with raw intrinsics (zero biases, no effects).
        dead_reckoning: 2 s IMU dead-reckoning segments from the mocap state.
        spectrum_span_s: mocap-time span the IMU-domain analysis covers.
    """

    stage_spectra: Mapping[str, StageSpectrum] = field(default_factory=dict)
    imu_analysis: ResidualAnalysis | None = None
    imu_before: tuple[Array, Array, Array] | None = None
    dead_reckoning: DeadReckoning | None = None
    spectrum_span_s: tuple[float, float] | None = None


@dataclass(frozen=True)
class TakeSeries:
    """One take's series.

    Attributes:
        residuals: the stages' residual series, by stage name (empty without the solver's).
        scene: poses, gaps and frames (None: the take has no session to show).
        imu: the IMU predicted over the whole take (the recording's).
        dead_reckoning: a segment every 10 s (the recording's).
        figures: the report's figures (None: not computed, or no solver's session).
    """

    residuals: Mapping[str, ResidualSeries] = field(default_factory=dict)
    scene: Scene | None = None
    imu: ImuPrediction | None = None
    dead_reckoning: DeadReckoning | None = None
    figures: ReportFigures | None = None


@dataclass(frozen=True)
class OutputSeries:
    """Everything the outputs draw beyond the result file.

    Attributes:
        takes: per take in input order (the first is the session the result describes).
        solver: the position stage's iterates (None: not kept).
        clock: the coarse clock search's curve (None: the offset was given, or not kept).
        steps: ``(label, {name: ResidualSeries})`` per diagnosis step: each step's low-band
            IMU residuals and position-factor innovations.
    """

    takes: tuple[TakeSeries, ...] = ()
    solver: SolverHistory | None = None
    clock: ClockCurve | None = None
    steps: tuple[tuple[str, Mapping[str, ResidualSeries]], ...] = ()

    @property
    def first(self) -> TakeSeries | None:
        return self.takes[0] if self.takes else None
