"""Plots of a calibration (PNG bytes): clock search, stage residuals and spectra, IMU-domain
spectra against the noise floor, segments, trajectory and mocap gaps.

Inputs are plain arrays and core result types; nothing here computes an estimate.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.parameters import TIME_OFFSET, TRANSLATION
from mocap_calib.core.result.series import ResidualSeries
from mocap_calib.core.result.verdicts import SegmentRecord
from mocap_calib.report.html.mpl import (
    AXIS_COLORS,
    every,
    log_axes,
    new_figure,
    styled,
    thin,
    to_png,
)

Array = NDArray[np.float64]

#: How residual units are shown (file unit -> (shown unit, factor)).
SHOWN_UNIT = {"m": ("mm", 1e3), "m/s": ("mm/s", 1e3)}


def clock_png(lags: Array, score: Array, chosen: float, candidates: Sequence[tuple[float, float]],
              peak_z: float, margin_z: float, fine: float | None, min_peak_z: float) -> bytes:
    """Correlation statistic against ``t_d`` (whole range and around the peak)."""
    score = np.where(score > -1e3, score, np.nan)  # lags without enough overlap
    with styled():
        fig = new_figure(9.5, 2.8, left=0.07, bottom=0.16, top=0.9, wspace=0.18)
        a1, a2 = fig.subplots(1, 2, width_ratios=[3, 2])
        t, z = thin(lags, score)
        a1.plot(t, z, color="#444", lw=0.7)
        a1.axhline(min_peak_z, color="#999", ls=":", lw=0.8, label=f"resolved above {min_peak_z:g}")
        for k, (td, zc) in enumerate(candidates[1:]):
            a1.plot(td, zc, "x", color="#ff7f0e", ms=6, label="other peaks" if k == 0 else None)
        a1.plot(chosen, peak_z, "o", color="#d62728", ms=6,
                label=f"chosen {1e3 * chosen:.2f} ms (z {peak_z:.1f})")
        if candidates[1:]:
            a1.annotate("", xy=(chosen, peak_z), xytext=(chosen, peak_z - margin_z),
                        arrowprops={"arrowstyle": "<->", "color": "#d62728"})
        a1.set_xlabel("t_d (s)")
        a1.set_ylabel("combined statistic (null sigmas)")
        a1.set_title(f"clock search: peak {peak_z:.1f}, margin {margin_z:.1f} null sigmas", y=1.0)
        a1.legend(loc="upper right")
        sel = np.abs(lags - chosen) <= 0.5
        a2.plot(1e3 * lags[sel], score[sel], ".-", color="#444", ms=2, lw=0.7)
        a2.axvline(1e3 * chosen, color="#d62728", lw=1.0, label=f"coarse {1e3 * chosen:.2f} ms")
        if fine is not None:
            a2.axvline(1e3 * fine, color="#2ca02c", lw=1.2, ls="--",
                       label=f"fine {1e3 * fine:.3f} ms")
        a2.set_xlabel("t_d (ms)")
        a2.set_title("around the peak", y=1.0)
        a2.legend(loc="lower center")
        return to_png(fig)


#: Shading of the IMU gaps on time plots: bridged, split.
IMU_GAP_COLORS = ("#fdae6b", "#bcbddc")


def shade_imu_gaps(ax, spans: Array, split_s: float, label: bool = True) -> None:
    """Shade the IMU gaps ``spans`` ((G, 2) mocap time) on a time axis; longer than
    ``split_s``: split the session (another colour)."""
    for kind in (False, True):
        sel = [(a, b) for a, b in spans if (b - a > split_s) == kind]
        for j, (a, b) in enumerate(sel):
            ax.axvspan(a, b, color=IMU_GAP_COLORS[int(kind)], alpha=0.6, lw=0, zorder=0,
                       label=(f"IMU gap, {'split' if kind else 'bridged'} ({len(sel)})"
                              if label and j == 0 else None))


def stage_png(name: str, s: ResidualSeries, removed_t: Array,
              spectrum: tuple[Array, Array, Array, Array] | None,
              imu_gaps: Array | None = None, split_s: float = 0.5) -> bytes:
    """One stage: residuals before (grey) and after (per axis) over time, robust weights with
    the down-weighted samples and removed spikes below, and the residual spectra against the
    noise floor (``spectrum``: freq, before, after, floor per axis); ``imu_gaps``: (G, 2)
    mocap-time spans shaded on both time plots."""
    unit, k = SHOWN_UNIT.get(s.unit, (s.unit, 1.0))
    order = np.argsort(s.t, kind="stable")  # overlapping windows are not in time order
    t_all = s.t[order]
    with styled():
        fig = new_figure(9.5, 3.0, left=0.07, right=0.985, top=0.9, bottom=0.14, wspace=0.22,
                         hspace=0.08)
        gs = fig.add_gridspec(2, 2, width_ratios=[2.3, 1], height_ratios=[3, 1])
        ax = fig.add_subplot(gs[0, 0])
        w = fig.add_subplot(gs[1, 0], sharex=ax)
        for i in range(3):
            ax.plot(*thin(t_all, k * s.before[order, i]), color="#bbb", lw=0.5,
                    label="before" if i == 0 else None)
        for i in range(3):
            ax.plot(*thin(t_all, k * s.after[order, i]), color=AXIS_COLORS[i], lw=0.6,
                    label=f"after {'xyz'[i]}")
        if imu_gaps is not None and len(imu_gaps):
            shade_imu_gaps(ax, imu_gaps, split_s)
            shade_imu_gaps(w, imu_gaps, split_s, label=False)
        ax.set_ylabel(unit)
        ax.legend(loc="upper right", ncols=4)
        ax.set_title(f"{name} stage: residuals before and after the solve", y=1.0)
        ax.tick_params(labelbottom=False)
        wt = s.weight[order]
        w.plot(*thin(t_all, wt), color="#555", lw=0.6)
        out = wt < 0.5
        if np.any(out):
            w.plot(t_all[out], wt[out], "v", color="#d62728", ms=3,
                   label=f"{int(out.sum())} down-weighted")
        for j, tr in enumerate(removed_t):
            w.axvline(tr, color="#9467bd", lw=0.8, label="removed spike" if j == 0 else None)
        w.set_ylim(-0.1, 1.15)
        w.set_ylabel("weight")
        w.set_xlabel("mocap time (s)")
        if np.any(out) or len(removed_t):
            w.legend(loc="lower right", ncols=2)
        sp = fig.add_subplot(gs[:, 1])
        if spectrum is not None:
            f, before, after, floor = spectrum
            sp.plot(f[1:], k**2 * before[1:].mean(axis=1), color="#bbb", lw=0.8,
                    label="before")
            for i in range(3):
                sp.plot(f[1:], k**2 * after[1:, i], color=AXIS_COLORS[i], lw=0.7)
            sp.axhline(k**2 * float(np.mean(floor)), color="k", ls="--", lw=0.9,
                       label="noise floor")
            log_axes(sp)
            sp.legend(loc="lower left")
        sp.set_title(f"spectra ({unit}^2/Hz)", y=1.0)
        sp.set_xlabel("Hz")
        return to_png(fig)


def imu_spectra_png(freq: Array, gyro: Array, gyro_floor: Array, accel: Array,
                    accel_floor: Array, before: tuple[Array, Array, Array] | None,
                    cutoff_hz: float) -> bytes:
    """Measured-minus-predicted IMU spectra against the Monte Carlo noise floor."""
    with styled():
        fig = new_figure(9.5, 2.8, left=0.08, bottom=0.16, wspace=0.25)
        axes = fig.subplots(1, 2)
        for j, (ax, name, psd, fl, u) in enumerate(
                ((axes[0], "gyro", gyro, gyro_floor, "(rad/s)^2/Hz"),
                 (axes[1], "accel", accel, accel_floor, "(m/s^2)^2/Hz"))):
            f = freq[1:]
            if before is not None:
                ax.plot(before[0][1:], before[1 + j][1:].mean(axis=1), color="#bbb", lw=0.8,
                          label="before (raw intrinsics)")
            for i in range(3):
                ax.plot(f, psd[1:, i], color=AXIS_COLORS[i], lw=0.7, label=f"after {'xyz'[i]}")
            ax.plot(f, fl[1:].mean(axis=1), color="k", ls="--", lw=1.0, label="noise floor")
            log_axes(ax)
            ax.axvline(cutoff_hz, color="#9467bd", ls=":", lw=0.8, label=f"{cutoff_hz:g} Hz band")
            ax.set_title(f"{name}: measured minus predicted", y=1.0)
            ax.set_xlabel("Hz")
            ax.set_ylabel(u)
        axes[1].legend(loc="lower left", ncols=2)
        return to_png(fig)


def segments_png(segments: Sequence[SegmentRecord], time_offset: Array | None,
                 translation: Array | None) -> bytes:
    """Per-segment t_d and p_MI with 1-sigma bars, relative to the whole session's estimate
    (``time_offset``, ``translation``; None: not determined)."""
    with styled():
        fig = new_figure(9.5, 2.4, left=0.07, bottom=0.2, wspace=0.2)
        a1, a2 = fig.subplots(1, 2)
        mid = np.array([0.5 * (s.start_s + s.end_s) for s in segments])
        span = float(np.ptp(mid)) if len(mid) > 1 else 1.0
        td = [s.estimates[TIME_OFFSET] for s in segments]
        if all(e.value is not None for e in td):
            ref = 0.0 if time_offset is None else float(time_offset[0])
            a1.errorbar(mid, 1e3 * (np.array([float(e.value[0]) for e in td]) - ref),
                        yerr=1e3 * np.array([float(e.sigma[0]) for e in td]),
                        fmt="o", ms=3, capsize=3, color="#444")
            a1.axhline(0.0, color="k", lw=0.8)
            a1.set_title("t_d per segment minus whole session (ms)", y=1.0)
        else:  # a model without the clock offset: the segments fit none
            a1.set_axis_off()
            a1.set_title("t_d fixed (not in the model)", y=1.0)
        pref = np.zeros(3) if translation is None else np.asarray(translation, dtype=float)
        p = [s.estimates[TRANSLATION] for s in segments]
        for i in range(3):
            v = 1e3 * (np.array([e.value[i] for e in p]) - pref[i])
            e = 1e3 * np.array([q.sigma[i] for q in p])
            a2.errorbar(mid + (i - 1) * 0.02 * span, v, yerr=e, fmt="o", ms=3, capsize=3,
                        color=AXIS_COLORS[i], label="xyz"[i])
        a2.axhline(0.0, color="k", lw=0.8)
        a2.set_title("p_MI per segment minus whole session (mm)", y=1.0)
        a2.legend(loc="best", ncols=3)
        for ax in (a1, a2):
            ax.set_xlabel("segment middle (s)")
        return to_png(fig)


def trajectory_png(p_marker: Array, imu_segments: Sequence[Array], gap_points: Array,
                   removed_points: Array) -> bytes:
    """3D marker path, IMU dead-reckoned segments (calibrated) and the mocap gaps."""
    with styled():
        fig = new_figure(6.5, 5.0, left=0.0, right=1.0, top=1.0, bottom=0.02)
        ax = fig.add_subplot(projection="3d")
        p = p_marker[every(len(p_marker))]
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color="#1f77b4", lw=0.6, label="marker (mocap)")
        for j, seg in enumerate(imu_segments):
            ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="#ff7f0e", lw=1.4,
                    label="IMU dead reckoning, 2 s (calibrated)" if j == 0 else None)
        if len(gap_points):
            ax.scatter(gap_points[:, 0], gap_points[:, 1], gap_points[:, 2], color="#d62728",
                       s=14, marker="s", label=f"mocap gap ends ({len(gap_points) // 2} gaps)")
        if len(removed_points):
            ax.scatter(removed_points[:, 0], removed_points[:, 1], removed_points[:, 2],
                       color="#9467bd", s=12, marker="x", label="removed spikes")
        lo, hi = p_marker.min(axis=0), p_marker.max(axis=0)
        pad = 0.1 * max(float(np.max(hi - lo)), 1e-3)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_zlim(lo[2] - pad, hi[2] + pad)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        ax.legend(loc="upper left")
        return to_png(fig)


def gaps_png(tau: Array, gaps: Array, removed_t: Array, dr_t: Array, dr_before: Array,
             dr_after: Array, imu_gaps: Array | None = None, split_s: float = 0.5) -> bytes:
    """Mocap coverage over time (gaps, removed spikes), the IMU gaps ((G, 2) mocap time,
    shaded on both plots) and the dead-reckoning drift."""
    with styled():
        fig = new_figure(9.5, 2.6, left=0.07, bottom=0.16, top=0.9, hspace=0.35)
        a1, a2 = fig.subplots(2, 1, sharex=True, height_ratios=[0.6, 1])
        a1.broken_barh([(float(tau[0]), float(tau[-1] - tau[0]))], (0.2, 0.6), color="#9ecae1")
        if len(gaps):
            a1.broken_barh([(float(a), float(b - a)) for a, b in gaps], (0.0, 1.0),
                           color="#d62728")
        for tr in removed_t:
            a1.axvline(tr, color="#9467bd", lw=0.8)
        a1.set_yticks([])
        n_imu = 0 if imu_gaps is None else len(imu_gaps)
        if n_imu:
            shade_imu_gaps(a1, imu_gaps, split_s, label=False)
            shade_imu_gaps(a2, imu_gaps, split_s)
        a1.set_title(f"mocap coverage: {len(gaps)} gaps (red), {len(removed_t)} removed spikes "
                     f"(purple); {n_imu} IMU gaps shaded (orange: bridged, lilac: split)",
                     y=1.0)
        if len(dr_t):
            a2.plot(dr_t, 1e3 * np.maximum(dr_before, 1e-6), "o", color="#aaa", ms=3,
                    label="raw IMU")
            a2.plot(dr_t, 1e3 * np.maximum(dr_after, 1e-6), "o", color="#ff7f0e", ms=3,
                    label="calibrated")
            log_axes(a2, x=False)
        if len(dr_t) or n_imu:
            a2.legend(loc="upper right", ncols=4)
        a2.set_ylabel("2 s drift (mm)")
        a2.set_xlabel("mocap time (s)")
        return to_png(fig)
