"""The sections of a calibration report: result table, checks, clock search, residuals and
spectra, trajectory and mocap gaps.

:func:`calibration_sections` takes the result (with its in-memory diagnostics) and the
figures the workflow computed for the report (:class:`CalibrationExtras`); every number in a
table is tied to its key in the result YAML (see :mod:`.page`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.clock.search import MIN_PEAK_Z
from mocap_calib.core.diagnosis.dead_reckoning import DeadReckoning
from mocap_calib.core.diagnosis.predict import ResidualAnalysis
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.report.html import calib_plots as plots
from mocap_calib.report.html.page import Cell, Figure, Notes, Row, Section, Table
from mocap_calib.report.html.tables import flat, get, kv_rows, num
from mocap_calib.report.text import UNCERTAINTY_TERMS, UNCERTAINTY_UNITS, checks_lines

Array = NDArray[np.float64]
DEG = float(np.degrees(1.0))


@dataclass
class StageSpectrum:
    """Welch PSD of one stage's residuals (per axis) and the white floor its noise model
    assumes (per axis, in the residual's unit^2/Hz)."""

    unit: str
    freq: Array
    before: Array
    after: Array
    floor: Array


@dataclass
class CalibrationExtras:
    """What the workflow computed for the report beyond the result.

    Attributes:
        imu_analysis: measured-minus-predicted IMU residuals with the Monte Carlo noise floor.
        imu_before: (freq, gyro, accel) PSDs with raw intrinsics (zero biases, no effects).
        stage_spectra: per stage name.
        dead_reckoning: 2 s IMU dead-reckoning segments from the mocap state.
        spectrum_span_s: mocap-time span the IMU-domain analysis covers.
        seconds: time spent computing these (s).
    """

    imu_analysis: ResidualAnalysis | None = None
    imu_before: tuple[Array, Array, Array] | None = None
    stage_spectra: dict[str, StageSpectrum] = field(default_factory=dict)
    dead_reckoning: DeadReckoning | None = None
    spectrum_span_s: tuple[float, float] | None = None
    seconds: float = 0.0


#: Rows of the result table: (label, key, sigma key, shown unit, scale, sigma scale).
_PARAMS = (
    ("gyro_bias", "gyro_bias", "sigma/gyro_bias", "rad/s", 1.0, 1.0),
    ("accel_bias", "accel_bias", "sigma/accel_bias", "m/s^2", 1.0, 1.0),
    ("R_MI quaternion (wxyz)", "T_marker_imu/rotation_wxyz", None, "-", 1.0, 1.0),
    ("R_MI rotation (1-sigma per axis)", None, "sigma/rotation", "deg", 1.0, DEG),
    ("p_MI", "T_marker_imu/translation", "sigma/translation", "mm", 1e3, 1e3),
    ("gravity_in_mocap (1-sigma: tilt)", "gravity_in_mocap", "sigma/gravity_in_mocap", "- / deg",
     1.0, DEG),
    ("time_offset t_d", "time_offset", "sigma/time_offset", "ms", 1e3, 1e3),
)


def _param_rows(d: dict[str, Any]) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for label, key, skey, unit, k, ks in _PARAMS:
        vals = list(flat(get(d, key), key)) if key is not None else []
        sigs = list(flat(get(d, skey), skey)) if skey is not None else []
        n = max(len(vals), len(sigs))
        for i in range(n):
            comp = "" if n == 1 else ("wxyz" if n == 4 else "xyz")[i]
            sig = sigs[i] if i < len(sigs) and len(sigs) == len(vals) else None
            v_cell = (num(vals[i][0], vals[i][1], k, None if sig is None or sig[1] is None
                          else float(sig[1])) if i < len(vals) else Cell(""))
            s_cell = num(sigs[i][0], sigs[i][1], ks, digits=2) if i < len(sigs) else Cell("")
            rows.append([label if i == 0 else "", comp, v_cell, s_cell, unit])
    for name, rec in d.get("effects", {}).items():
        for p, val in rec.items():
            if p == "sigma":
                continue
            sig = dict(flat(rec.get("sigma"), f"effects/{name}/sigma"))
            for j, (key, v) in enumerate(flat(val, f"effects/{name}/{p}")):
                skey = key.replace(f"effects/{name}/{p}", f"effects/{name}/sigma", 1)
                s = sig.get(skey)
                rows.append([f"{name}.{p}" if j == 0 else "", key.rsplit("/", 1)[-1]
                             if key != f"effects/{name}/{p}" else "",
                             num(key, v, sigma=s), num(skey, s, digits=2) if skey in sig
                             else Cell(""), ""])
    return rows


def _stage_rows(d: dict[str, Any]) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for i, st in enumerate(d.get("stages", [])):
        unit, k = plots.SHOWN_UNIT.get(st["unit"], (st["unit"], 1.0))
        for a in range(3):
            rows.append([f"{st['name']} ({unit})" if a == 0 else "", "xyz"[a],
                         num(f"stages/{i}/rms_before/{a}", st["rms_before"][a], k, digits=4),
                         num(f"stages/{i}/rms_after/{a}", st["rms_after"][a], k, digits=4),
                         num(f"stages/{i}/n_factors", st["n_factors"]) if a == 0 else "",
                         num(f"stages/{i}/outliers", st["outliers"]) if a == 0 else "",
                         num(f"stages/{i}/chi2_per_dof", st["chi2_per_dof"], digits=4)
                         if a == 0 else ""])
    return rows


def _verdict(d: dict[str, Any]) -> tuple[str, str] | None:
    pl = d.get("plausibility") or {}
    if not pl:
        return None
    v = str(pl.get("verdict"))
    return (f"plausibility: {v}", "ok" if v == "plausible" else "bad")


def result_section(r: CalibrationResult, d: dict[str, Any]) -> Section:
    """The estimates with 1-sigma, the stages, warnings and unobservable parameters."""
    blocks: list[Any] = [Row([
        Table("result-table", ("parameter", "axis", "estimate", "1-sigma", "unit"),
              _param_rows(d), f"Calibration ({d.get('model')}), 1-sigma uncertainties"),
        Table("stages-table", ("stage", "axis", "RMS before", "RMS after", "factors",
                               "outliers", "chi2/dof"), _stage_rows(d),
              "Residual RMS per stage"),
    ])]
    if r.unobservable:
        blocks.append(Notes("unobservable", [f"{k}: {v}" for k, v in r.unobservable.items()],
                            "warning"))
    blocks.append(Notes("warnings", list(r.notes) or ["no warnings"],
                        "warning" if r.notes else "ok"))
    steps = (d.get("solver") or {}).get("step_seconds") or {}
    if steps:
        rows: list[list[str | Cell]] = [
            [k.replace("_", " "), num(f"solver/step_seconds/{k}", v, digits=3)]
            for k, v in steps.items()]
        rows.append(["total (calibration)",
                     num("solver/total_seconds", d["solver"].get("total_seconds"), digits=3)])
        blocks.append(Table("steps-table", ("step", "seconds"), rows, "Time per step"))
    return Section("sec-result", "Result", blocks)


def _consistency_blocks(d: dict[str, Any], r: CalibrationResult) -> list[Any]:
    cons = d.get("consistency") or {}
    segs = cons.get("segments") or []
    if not segs:
        return [f"Consistency: {cons.get('note', 'not computed')}"]
    rows: list[list[str | Cell]] = []
    for i, s in enumerate(segs):
        p = f"consistency/segments/{i}"
        sg = s.get("sigma", {})
        rows.append([str(i + 1), num(f"{p}/start_s", s["start_s"], digits=6),
                     num(f"{p}/end_s", s["end_s"], digits=6),
                     num(f"{p}/time_offset", s.get("time_offset"), 1e3,
                         sg.get("time_offset")),
                     num(f"{p}/sigma/time_offset", sg.get("time_offset"), 1e3, digits=2),
                     *[num(f"{p}/translation/{a}", s["translation"][a], 1e3,
                           sg.get("translation", [None] * 3)[a]) for a in range(3)]])
    summary = []
    for what in ("max_pairwise_z", "birge_ratio", "sigma_factor"):
        for k, v in (cons.get(what) or {}).items():
            summary.append([what, k, num(f"consistency/{what}/{k}", v, digits=4)])
    full = {"time_offset": r.time_offset,
            "translation": None if r.translation is None else list(r.translation)}
    png = plots.segments_png(segs, full) if segs and "translation" in segs[0] else None
    return [Table("consistency-table", ("segment", "start (s)", "end (s)", "t_d (ms)",
                                        "1-sigma (ms)", "p_MI x (mm)", "p_MI y (mm)",
                                        "p_MI z (mm)"), rows,
                  "Independent segments, each calibrated on its own"),
            Table("consistency-summary", ("figure", "parameter", "value"), summary,
                  "Agreement of the segments"),
            Figure("fig-consistency", "Segments: t_d and p_MI with 1-sigma against the whole "
                   "session's estimate", png)]


def checks_section(r: CalibrationResult, d: dict[str, Any]) -> Section:
    """Plausibility verdict, segment consistency, sensitivity to the noise densities."""
    pl = d.get("plausibility") or {}
    blocks: list[Any] = [Notes("checks-lines", checks_lines(r) or ["no checks recorded"])]
    if pl.get("failed"):
        blocks.append(Notes("plausibility-failed", [f"FAILED: {x}" for x in pl["failed"]],
                            "warning"))
    row: list[Any] = []
    if pl:
        rows = [["verdict", num("plausibility/verdict", pl.get("verdict"))]]
        rows += kv_rows(pl.get("figures") or {}, "plausibility/figures")
        row.append(Table("plausibility-table", ("check", "value"), rows,
                         "Plausibility: physical checks"))
    cons = _consistency_blocks(d, r)
    row += [b for b in cons if isinstance(b, Table) and b.id == "consistency-summary"]
    sens = _sensitivity_table(d.get("sensitivity") or {})
    if sens is not None:
        row.append(sens)
    unc = _uncertainty_table(d.get("uncertainty") or {})
    if unc is not None:
        row.append(unc)
    blocks.append(Row(row))
    blocks += [b for b in cons if not (isinstance(b, Table) and b.id == "consistency-summary")]
    return Section("sec-checks", "Checks: plausibility, consistency, sensitivity", blocks)


def _uncertainty_table(unc: dict[str, Any]) -> Table | None:
    """Per parameter group and axis, every term of the reported sigma (the rule in
    core/checks/verdict.py), so that a reader sees which one dominates."""
    rows: list[list[str | Cell]] = []
    for key, (unit, k) in UNCERTAINTY_UNITS.items():
        u = unc.get(key)
        if not u:
            continue
        for a in range(len(u["total"])):
            rows.append([f"{key} ({unit})" if a == 0 else "", "xyz"[a] if len(u["total"]) > 1
                         else ""]
                        + [num(f"uncertainty/{key}/{t}/{a}", u[t][a], k, digits=3)
                           if u.get(t) is not None else "-" for t, _ in UNCERTAINTY_TERMS]
                        + [num(f"uncertainty/{key}/consistency_factor",
                               u.get("consistency_factor"), digits=3) if a == 0 else ""])
    if not rows:
        return None
    head = ["parameter", "axis", *(label for _, label in UNCERTAINTY_TERMS),
            "consistency factor"]
    return Table("uncertainty-table", head, rows, "Sigma: the terms of the rule "
                 "(total = max(sqrt((factor x statistical)^2 + shifts^2), largest move))")


def _sensitivity_table(sens: dict[str, Any]) -> Table | None:
    """Per parameter, how many sigmas it moves under each scaling of the noise densities
    (total and statistical sigmas)."""
    cols = [(what, f) for what in ("moved_sigmas", "moved_statistical_sigmas")
            for f in (sens.get(what) or {})]
    if not cols:
        return None
    params = list(dict.fromkeys(k for what, f in cols for k in sens[what][f]))
    rows: list[list[str | Cell]] = []
    for k in params:
        rows.append([k] + [num(f"sensitivity/{what}/{f}/{k}", sens[what][f][k], digits=3)
                           if k in sens[what][f] else "" for what, f in cols])
    head = ["parameter"] + [f"{f} ({'total' if what == 'moved_sigmas' else 'statistical'})"
                            for what, f in cols]
    return Table("sensitivity-table", head, rows, "Sensitivity: sigmas moved when the IMU "
                 "noise densities are scaled")


def clock_section(r: CalibrationResult, d: dict[str, Any]) -> Section:
    """The coarse clock search: curve, chosen peak, margin and the fine estimate."""
    c = d.get("clock") or {}
    if not c:
        return Section("sec-clock", "Clock search", ["No search: the clock offset was given."])
    rows = [[k, num(f"clock/{k}", c.get(k), digits=8 if "offset" in k else 4)]
            for k in ("coarse_time_offset", "peak_z", "margin_z", "second_best_time_offset",
                      "fine_time_offset") if k in c]
    rows += [[f"candidate {i + 1}", Cell(f"t_d {x['time_offset']:.6g} s, z {x['z']:.4g}")]
             for i, x in enumerate(c.get("candidates", []))]
    rows.append(["signals", ", ".join(c.get("signals", []))])
    blocks: list[Any] = [Table("clock-table", ("figure", "value"), rows, "Clock search")]
    cs = r.diagnostics.trace.clock if r.diagnostics and r.diagnostics.trace else None
    if cs is not None and len(cs.lags):
        fine = c.get("fine_time_offset")
        png = plots.clock_png(cs.lags, cs.score, cs.time_offset, cs.candidates, cs.peak_z,
                              cs.margin_z, fine, MIN_PEAK_Z)
        blocks.append(Figure(
            "fig-clock", f"Clock search: combined correlation statistic against t_d; chosen "
            f"peak {1e3 * cs.time_offset:.3f} ms at {cs.peak_z:.2f} null sigmas, margin "
            f"{cs.margin_z:.2f} over the next peak; fine estimate "
            + ("-" if fine is None else f"{1e3 * fine:.3f} ms"), png,
            data={"peak-z": f"{c['peak_z']!r}", "margin-z": f"{c['margin_z']!r}",
                  "coarse-time-offset": f"{c['coarse_time_offset']!r}",
                  "fine-time-offset": f"{fine!r}"}))
    return Section("sec-clock", "Clock search", blocks)
