"""Report sections of the IMU-only commands: multi-position intrinsics (static intervals on the
accel norm, per-pose residuals) and Allan deviation (curves with the fitted lines)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.report.html.mpl import (
    AXIS_COLORS,
    log_axes,
    new_figure,
    styled,
    thin,
    to_png,
)
from mocap_calib.report.html.page import Cell, Figure, Notes, Section, Table
from mocap_calib.report.html.tables import flat, get, kv_rows, num

if TYPE_CHECKING:
    from mocap_calib.core.intrinsics.multipos.result import MultiposResult
    from mocap_calib.core.intrinsics.noise_result import AllanResult, SensorNoise
    from mocap_calib.core.model.types import ImuSamples

Array = NDArray[np.float64]


@dataclass
class PoseResiduals:
    """Per static pose: time (s from the log start) and ``|h| - g`` (m/s^2); per rotation:
    time and the gravity-direction error after integrating it (rad)."""

    pose_t: Array
    accel: Array
    rotation_t: Array
    gyro: Array


def static_png(t: Array, norm: Array, intervals: Array, k: float) -> bytes:
    """Accel norm over time with the static intervals shaded."""
    with styled():
        fig = new_figure(9.5, 2.6, left=0.07, bottom=0.17)
        ax = fig.add_subplot()
        for a, b in intervals:
            ax.axvspan(a, b, color="#2ca02c", alpha=0.18, lw=0)
        ax.plot(*thin(t, norm), color="#333", lw=0.6)
        ax.set_xlabel("time since log start (s)")
        ax.set_ylabel("|accel|")
        ax.set_title(f"accelerometer norm; green: {len(intervals)} static intervals "
                     f"(threshold multiple k = {k:g})", y=1.0)
        return to_png(fig)


def pose_png(r: PoseResiduals) -> bytes:
    """Per-pose accel residual and per-rotation gyro residual."""
    with styled():
        fig = new_figure(9.5, 2.5, left=0.08, bottom=0.18, wspace=0.25)
        a1, a2 = fig.subplots(1, 2)
        a1.stem(r.pose_t, 1e3 * r.accel, basefmt="k-")
        a1.set_title("per static pose: |h| - g (mm/s^2)", y=1.0)
        a1.set_xlabel("pose time (s)")
        if len(r.gyro):
            a2.stem(r.rotation_t, np.degrees(r.gyro), basefmt="k-")
        a2.set_title("per rotation: gravity-direction error (deg)", y=1.0)
        a2.set_xlabel("rotation time (s)")
        return to_png(fig)


def _matrix_rows(d: dict[str, Any], names: tuple[str, ...]) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for name in names:
        vals = list(flat(get(d, name), name))
        sigs = dict(flat(get(d, f"sigma/{name}"), f"sigma/{name}"))
        for j, (key, v) in enumerate(vals):
            skey = f"sigma/{key}"
            s = sigs.get(skey)
            idx = key[len(name) + 1:]
            rows.append([name if j == 0 else "", idx.replace("/", ","), num(key, v, sigma=s),
                         num(skey, s, digits=2) if skey in sigs else Cell("")])
    return rows


def multipos_report_sections(result: MultiposResult, imu: ImuSamples,
                             residuals: PoseResiduals | None) -> list[Section]:
    d = result.to_dict()
    names = ("accel_matrix", "accel_bias", "gyro_matrix", "gyro_bias") + (
        ("g_sensitivity",) if "g_sensitivity" in d else ())
    res_rows = kv_rows(d["residuals"], "residuals", digits=6)
    diag = {k: v for k, v in d["diagnostics"].items()
            if k not in ("static_intervals_s", "threshold_scan", "g_sensitivity_test")}
    blocks: list[Any] = [
        Table("multipos-table", ("parameter", "entry", "estimate", "1-sigma"),
              _matrix_rows(d, names), "Intrinsics (a_m = M_a f + b_a, w_m = M_g w + G f + b_g;"
              " SI units), 1-sigma"),
        Table("multipos-residuals", ("figure", "value"), res_rows, "Residuals"),
        Table("multipos-diagnostics", ("figure", "value"), kv_rows(diag, "diagnostics"),
              "Static detector and fit quality"),
    ]
    if result.poorly_determined:
        blocks.append(Notes("multipos-poor", [f"poorly determined: {p}"
                                              for p in result.poorly_determined], "warning"))
    x = imu if result.raw_input is None else result.raw_input.apply(imu)
    t = imu.t - imu.t[0]
    blocks.append(Figure(
        "fig-multipos-static", f"Accelerometer norm over time with the "
        f"{result.n_static_intervals} static intervals the detector kept (threshold multiple "
        f"k = {result.threshold_multiple:g})",
        static_png(t, np.linalg.norm(x.accel, axis=1), result.static_intervals - imu.t[0],
                   result.threshold_multiple),
        data={"intervals": str(result.n_static_intervals)}))
    if residuals is not None:
        acc_rms = float(np.sqrt(np.mean(residuals.accel**2)))
        gyr_rms = float(np.sqrt(np.mean(residuals.gyro**2))) if len(residuals.gyro) else 0.0
        blocks.append(Figure(
            "fig-multipos-residuals", f"Per-pose residuals: accelerometer |h| - g per static "
            f"interval (RMS {acc_rms:.6g} m/s^2) and the gyroscope's gravity-direction error "
            f"per rotation (RMS {gyr_rms:.6g} rad)", pose_png(residuals),
            data={"accel-rms-mps2": repr(acc_rms), "gyro-rms-rad": repr(gyr_rms),
                  "poses": str(len(residuals.accel))}))
    scan = [[num(f"diagnostics/threshold_scan/{i}/{k}", e.get(k), digits=6)
             for k in ("k", "n_intervals", "chi2")]
            for i, e in enumerate(d["diagnostics"].get("threshold_scan") or [])]
    if scan:
        blocks.append(Table("multipos-scan", ("k", "intervals", "accel chi2"), scan,
                            "Threshold scan"))
    return [Section("sec-multipos", "Multi-position intrinsics", blocks)]


_UNITS = {"gyroscope": ("rad/s", "rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)"),
          "accelerometer": ("m/s^2", "m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)")}


def allan_png(s: SensorNoise) -> bytes:
    """Allan deviation per axis: measured with 1-sigma, the fit, and the N, K, B lines."""
    unit = _UNITS[s.sensor][0]
    with styled():
        fig = new_figure(9.5, 3.0, left=0.07, bottom=0.16, wspace=0.2)
        axes = fig.subplots(1, 3, sharey=True)
        tau = s.tau
        for i, ax in enumerate(axes):
            ax.errorbar(tau, s.adev[i], yerr=s.adev_sigma[i], fmt=".", ms=3, lw=0.6,
                        color=AXIS_COLORS[i], label="measured")
            ax.plot(tau, s.adev_fit[i], color="k", lw=1.0, label="fit")
            ax.plot(tau, s.noise_density[i] / np.sqrt(tau), ls="--", color="#1f77b4", lw=0.8,
                    label=f"N {s.noise_density[i]:.3g}")
            K = s.random_walk_fit[i]
            if K > 0:
                ax.plot(tau, K * np.sqrt(tau / 3.0), ls="--", color="#2ca02c", lw=0.8,
                        label=f"K {K:.3g}")
            ax.axhline(0.664 * s.bias_instability[i], ls=":", color="#ff7f0e", lw=0.9,
                       label=f"B {s.bias_instability[i]:.3g}")
            lo = float(np.nanmin(s.adev[i])) / 3.0
            ax.set_ylim(lo, float(np.nanmax(s.adev[i])) * 3.0)
            log_axes(ax)
            ax.set_title(f"{s.sensor} {'xyz'[i]}", y=1.0)
            ax.set_xlabel("tau (s)")
            ax.legend(loc="upper right", fontsize=6.5)
        axes[0].set_ylabel(f"Allan deviation ({unit})")
        return to_png(fig)


def allan_report_sections(result: AllanResult) -> list[Section]:
    d = result.to_dict()
    rows: list[list[str | Cell]] = []
    for s in ("gyroscope", "accelerometer"):
        pa = d["per_axis"][s]
        _, nu, ku = _UNITS[s]
        for i in range(3):
            p = f"per_axis/{s}"
            rows.append([s if i == 0 else "", "xyz"[i],
                         num(f"{p}/noise_density/{i}", pa["noise_density"][i],
                             sigma=pa["noise_density_sigma"][i]),
                         num(f"{p}/noise_density_sigma/{i}", pa["noise_density_sigma"][i],
                             digits=2),
                         num(f"{p}/random_walk/{i}", pa["random_walk"][i],
                             sigma=pa["random_walk_sigma"][i]),
                         num(f"{p}/random_walk_sigma/{i}", pa["random_walk_sigma"][i], digits=2),
                         num(f"{p}/bias_instability/{i}", pa["bias_instability"][i], digits=4),
                         f"{nu}; {ku}"])
    kalibr = [[k, num(k, d[k], digits=6)] for k in (
        "gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
        "accelerometer_random_walk", "update_rate")]
    blocks: list[Any] = [
        Table("allan-kalibr", ("Kalibr key", "value"), kalibr,
              f"Noise model (Kalibr imu.yaml keys, {result.aggregate} over the axes)"),
        Table("allan-table", ("sensor", "axis", "N", "1-sigma", "K", "1-sigma", "B", "units"),
              rows, "Per axis: white noise N, rate random walk K (null: not resolved), bias "
                    "instability B")]
    if d.get("unobservable"):
        blocks.append(Notes("allan-unobservable", [f"{k}: {v}" for k, v in
                                                   d["unobservable"].items()], "warning"))
    for s in (result.gyroscope, result.accelerometer):
        blocks.append(Figure(
            f"fig-allan-{s.sensor}", f"{s.sensor}: overlapping Allan deviation per axis "
            "(points, 1-sigma bars) with the fitted model sqrt(N^2/tau + B^2 2ln2/pi + "
            "K^2 tau/3) and its lines: N/sqrt(tau), K sqrt(tau/3), 0.664 B", allan_png(s),
            data={"noise-density": ",".join(repr(float(v)) for v in s.noise_density)}))
    return [Section("sec-allan", "Allan deviation", blocks)]
