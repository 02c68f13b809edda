"""Calibration report sections from a take's series (:class:`TakeSeries`, computed with the
result): residuals per stage (time series, weights, outliers, spectra), IMU-domain spectra
against the noise floor, the 3D trajectory and the mocap and IMU gaps."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import IMU_BRIDGE_MAX_S
from mocap_calib.core.result.series import ReportFigures, Scene, TakeSeries
from mocap_calib.report.html import calib_plots as plots
from mocap_calib.report.html.mpl import fmt
from mocap_calib.report.html.page import Figure, Section, Table

Array = NDArray[np.float64]


def residuals_section(take: TakeSeries | None) -> Section:
    """Per stage: residuals before/after over time with weights, outliers and removed spikes,
    and their spectra; then the IMU-domain spectra against the noise floor."""
    blocks: list[Any] = []
    if take is None or not take.residuals:
        return Section("sec-residuals", "Residuals",
                       ["Residual series are not available (the result was read from a file)."])
    scene = solver_scene(take)
    extras = take.figures or ReportFigures()
    removed = scene.removed_tau if scene is not None else np.zeros(0)
    spans = scene.imu_gaps if scene is not None else np.zeros((0, 2))
    for name, s in take.residuals.items():
        n_out = int(np.sum(s.weight < 0.5))
        sp = extras.stage_spectra.get(name)
        spec = None if sp is None else (sp.freq, sp.before, sp.after, sp.floor)
        blocks.append(Figure(
            f"fig-residuals-{name}", f"{name} stage: residuals before (grey) and after "
            f"(colour) per axis over time; robust weights below, {n_out} down-weighted "
            f"samples marked, {len(removed)} removed mocap spikes as vertical lines; right: "
            "their spectra (Welch) against the white floor the stage's noise model assumes "
            f"(RMS after / sqrt(chi2/dof)); {len(spans)} IMU gaps shaded",
            plots.stage_png(name, s, removed, spec, spans, IMU_BRIDGE_MAX_S),
            data={"stage": name, "outliers": str(n_out), "removed-spikes": str(len(removed)),
                  "spectrum": "yes" if spec is not None else "no", **_span_data(spans)}))
    ra = extras.imu_analysis
    if ra is not None and len(ra.freq) > 2:
        span = extras.spectrum_span_s
        where = "" if span is None else f" over mocap time {span[0]:.1f}-{span[1]:.1f} s"
        blocks.append(Figure(
            "fig-spectra-imu", "IMU measured minus predicted from the mocap through the "
            f"calibrated model{where}: spectra per axis against the noise floor (IMU white "
            "noise, bias wander and mocap noise through the same processing; Monte Carlo); "
            "grey: with raw intrinsics",
            plots.imu_spectra_png(ra.freq, ra.gyro_psd, ra.gyro_psd_floor, ra.accel_psd,
                                  ra.accel_psd_floor, extras.imu_before, ra.cutoff_hz)))
        rows = [[sensor, "xyz"[i], fmt(rms[i]), fmt(floor[i]), fmt(rms[i] / floor[i], 3), unit]
                for sensor, rms, floor, unit in (("gyro", ra.gyro_rms, ra.gyro_floor, "rad/s"),
                                                 ("accel", ra.accel_rms, ra.accel_floor,
                                                  "m/s^2"))
                for i in range(3)]
        blocks.append(Table("imu-residual-table", ("sensor", "axis", "RMS", "noise floor",
                                                   "ratio", "unit"), rows,
                            f"IMU residual below {ra.cutoff_hz:g} Hz against its noise floor"
                            + where))
    return Section("sec-residuals", "Residuals per stage and spectra", blocks)


def solver_scene(take: TakeSeries | None) -> Scene | None:
    """The take's scene if it is the session the solver used (a report shows no other)."""
    scene = take.scene if take is not None else None
    return scene if scene is not None and scene.from_solver else None


def _span_data(spans: Array) -> dict[str, str]:
    """The IMU gap spans as ``data-*`` attributes (mocap time, s)."""
    return {"imu-gaps": str(len(spans)),
            "imu-gap-starts-s": ",".join(f"{a:.4f}" for a in spans[:, 0]),
            "imu-gap-ends-s": ",".join(f"{b:.4f}" for b in spans[:, 1])}


def _imu_gaps_table(spans: Array) -> Table:
    rows = [[f"{a:.3f}", f"{b:.3f}", f"{1e3 * (b - a):.0f}",
             "split" if b - a > IMU_BRIDGE_MAX_S else "bridged"] for a, b in spans[:50]]
    return Table("imu-gaps-table", ("gap start (s)", "gap end (s)", "length (ms)", "done"), rows,
                 "IMU gaps (mocap time: last sample before, first after)"
                 + (f" (first 50 of {len(spans)})" if len(spans) > 50 else ""))


def trajectory_section(take: TakeSeries | None) -> Section:
    """3D marker path with the IMU's dead-reckoned segments, and the mocap gaps over time."""
    s = solver_scene(take)
    if s is None:
        return Section("sec-trajectory", "Trajectory and mocap gaps",
                       ["The trajectory is not available (the result was read from a file)."])
    extras = (take.figures if take is not None else None) or ReportFigures()
    i = s.gap_index
    gaps = np.stack([s.tau[i], s.tau[i + 1]], axis=1) if len(i) else np.zeros((0, 2))
    spans = s.imu_gaps
    gap_pts = np.concatenate([s.p_WM[i], s.p_WM[i + 1]]) if len(i) else np.zeros((0, 3))
    rem, rem_pts = s.removed_tau, s.removed_p_WM
    dr = extras.dead_reckoning
    segs = [] if dr is None else list(dr.p_after)
    dr_t = np.zeros(0) if dr is None else dr.tau[:, 0]
    before = np.zeros(0) if dr is None else dr.position_error("before")
    after = np.zeros(0) if dr is None else dr.position_error("after")
    drift = ("" if dr is None else f"; median 2 s drift {1e3 * np.median(after):.1f} mm "
             f"calibrated, {1e3 * np.median(before):.1f} mm raw")
    blocks: list[Any] = [
        Figure("fig-trajectory", f"3D path of the marker (mocap) and {len(segs)} IMU "
               f"dead-reckoning segments of 2 s from the mocap state through the calibrated "
               f"model; {len(gaps)} mocap gaps marked at their ends",
               plots.trajectory_png(s.p_WM, segs, gap_pts, rem_pts),
               data={"gaps": str(len(gaps)), "imu-segments": str(len(segs))}),
        Figure("fig-gaps", f"Mocap coverage over time: {len(gaps)} gaps longer than "
               f"{1e3 * s.gap:.0f} ms, {len(rem)} removed spikes; {len(spans)} IMU gaps shaded; "
               f"IMU dead-reckoning drift after 2 s per segment{drift}",
               plots.gaps_png(s.tau, gaps, rem, dr_t, before, after, spans, IMU_BRIDGE_MAX_S),
               data={"gaps": str(len(gaps)), "removed-spikes": str(len(rem)),
                     "gap-starts-s": ",".join(f"{a:.3f}" for a in gaps[:, 0]),
                     "gap-ends-s": ",".join(f"{b:.3f}" for b in gaps[:, 1]),
                     **_span_data(spans)}),
    ]
    if len(spans):
        blocks.append(_imu_gaps_table(spans))
    if len(gaps):
        rows = [[f"{a:.3f}", f"{b:.3f}", f"{1e3 * (b - a):.0f}"] for a, b in gaps[:50]]
        blocks.append(Table("gaps-table", ("gap start (s)", "gap end (s)", "length (ms)"), rows,
                            "Mocap gaps" + (f" (first 50 of {len(gaps)})" if len(gaps) > 50
                                            else "")))
    return Section("sec-trajectory", "Trajectory, mocap and IMU gaps", blocks)
