"""The sections of a calibration report: result table, checks, clock search, residuals and
spectra, trajectory and mocap gaps.

:func:`calibration_sections` takes the result and the series computed with it for the outputs
(:class:`~mocap_calib.core.result.series.OutputSeries`); every number in a table is tied to
its key in the result YAML (see :mod:`.page`).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from mocap_calib.core.model.parameters import COMPARED, PARAMETERS, TIME_OFFSET, TRANSLATION
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.estimate import plain
from mocap_calib.core.result.series import ClockCurve
from mocap_calib.report.html import calib_plots as plots
from mocap_calib.report.html.page import Cell, Figure, Notes, Row, Section, Table
from mocap_calib.report.html.tables import flat, kv_rows, num
from mocap_calib.report.text import UNCERTAINTY_TERMS, checks_lines


def _component_rows(label: str, unit: str, key: str | None, value: Any, scale: float,
                    skey: str | None, sigma: Any, sscale: float) -> list[list[str | Cell]]:
    """One row per component of a value (file form at ``key``) with its sigma (at ``skey``);
    a value's shown precision follows its sigma when they have as many components."""
    vals = list(flat(value, key)) if key is not None else []
    sigs = list(flat(sigma, skey)) if skey is not None else []
    n = max(len(vals), len(sigs))
    rows: list[list[str | Cell]] = []
    for i in range(n):
        comp = "" if n == 1 else ("wxyz" if n == 4 else "xyz")[i]
        sig = sigs[i] if i < len(sigs) and len(sigs) == len(vals) else None
        v_cell = (num(vals[i][0], vals[i][1], scale, None if sig is None or sig[1] is None
                      else float(sig[1])) if i < len(vals) else Cell(""))
        s_cell = num(sigs[i][0], sigs[i][1], sscale, digits=2) if i < len(sigs) else Cell("")
        rows.append([label if i == 0 else "", comp, v_cell, s_cell, unit])
    return rows


def _param_rows(r: CalibrationResult) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for p in PARAMETERS.values():
        pr = p.printed
        key, skey = "/".join(p.value_key), f"sigma/{p.sigma_key}"
        value, sigma = plain(p, r.value(p)), plain(p, r.sigma(p))
        if p.form == "so3":  # the value as a quaternion, the sigma in the tangent
            rows += _component_rows(f"{pr.label} quaternion (wxyz)", "-", key, value, 1.0,
                                    None, None, 1.0)
            rows += _component_rows(f"{pr.label} rotation (1-sigma per axis)", pr.sigma_unit,
                                    None, None, 1.0, skey, sigma, pr.sigma_scale)
            continue
        label = pr.label + (" (1-sigma: tilt)" if p.form == "s2" else "")
        rows += _component_rows(label, pr.unit, key, value, pr.value_scale, skey, sigma,
                                pr.sigma_scale)
    for name, rec in r.effects.items():
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


def _stage_rows(r: CalibrationResult) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for i, st in enumerate(r.stages):
        unit, k = plots.SHOWN_UNIT.get(st.unit, (st.unit, 1.0))
        for a in range(3):
            rows.append([f"{st.name} ({unit})" if a == 0 else "", "xyz"[a],
                         num(f"stages/{i}/rms_before/{a}", st.rms_before[a], k, digits=4),
                         num(f"stages/{i}/rms_after/{a}", st.rms_after[a], k, digits=4),
                         num(f"stages/{i}/n_factors", st.n_factors) if a == 0 else "",
                         num(f"stages/{i}/outliers", st.outliers) if a == 0 else "",
                         num(f"stages/{i}/chi2_per_dof", st.chi2_per_dof, digits=4)
                         if a == 0 else ""])
    return rows


def result_section(r: CalibrationResult) -> Section:
    """The estimates with 1-sigma, the stages, warnings and unobservable parameters."""
    blocks: list[Any] = [Row([
        Table("result-table", ("parameter", "axis", "estimate", "1-sigma", "unit"),
              _param_rows(r), f"Calibration ({r.model}), 1-sigma uncertainties"),
        Table("stages-table", ("stage", "axis", "RMS before", "RMS after", "factors",
                               "outliers", "chi2/dof"), _stage_rows(r),
              "Residual RMS per stage"),
    ])]
    if r.unobservable:
        blocks.append(Notes("unobservable", [f"{k}: {v}" for k, v in r.unobservable.items()],
                            "warning"))
    if r.degraded:
        blocks.append(Notes("degraded", [x.line() for x in r.degraded], "warning"))
    blocks.append(Notes("warnings", list(r.notes) or ["no warnings"],
                        "warning" if r.notes else "ok"))
    steps = r.solver.step_seconds or {}
    if steps:
        rows: list[list[str | Cell]] = [
            [k.replace("_", " "), num(f"solver/step_seconds/{k}", v, digits=3)]
            for k, v in steps.items()]
        rows.append(["total (calibration)",
                     num("solver/total_seconds", r.solver.total_seconds, digits=3)])
        blocks.append(Table("steps-table", ("step", "seconds"), rows, "Time per step"))
    return Section("sec-result", "Result", blocks)


def _consistency_blocks(r: CalibrationResult) -> list[Any]:
    cons = r.consistency
    segs = () if cons is None else cons.segments
    if not segs:
        return [f"Consistency: {cons.note if cons is not None and cons.note else 'not computed'}"]
    rows: list[list[str | Cell]] = []
    for i, s in enumerate(segs):
        p = f"consistency/segments/{i}"
        td, tr = s.estimates[TIME_OFFSET], s.estimates[TRANSLATION]
        td_v, td_s = plain(TIME_OFFSET, td.value), plain(TIME_OFFSET, td.sigma)
        tk, tsk = TIME_OFFSET.value_key[-1], f"sigma/{TIME_OFFSET.sigma_key}"
        pk = TRANSLATION.value_key[-1]
        rows.append([str(i + 1), num(f"{p}/start_s", s.start_s, digits=6),
                     num(f"{p}/end_s", s.end_s, digits=6),
                     num(f"{p}/{tk}", td_v, 1e3, td_s),
                     num(f"{p}/{tsk}", td_s, 1e3, digits=2),
                     *[num(f"{p}/{pk}/{a}", float(tr.value[a]), 1e3,
                           None if tr.sigma is None else float(tr.sigma[a]))
                       for a in range(3)]])
    summary = []
    for what in ("max_pairwise_z", "birge_ratio", "sigma_factor"):
        for q, v in getattr(cons, what).items():
            summary.append([what, q.symbol, num(f"consistency/{what}/{q.symbol}", v, digits=4)])
    png = plots.segments_png(segs, r.value(TIME_OFFSET), r.value(TRANSLATION))
    return [Table("consistency-table", ("segment", "start (s)", "end (s)", "t_d (ms)",
                                        "1-sigma (ms)", "p_MI x (mm)", "p_MI y (mm)",
                                        "p_MI z (mm)"), rows,
                  "Independent segments, each calibrated on its own"),
            Table("consistency-summary", ("figure", "parameter", "value"), summary,
                  "Agreement of the segments"),
            Figure("fig-consistency", "Segments: t_d and p_MI with 1-sigma against the whole "
                   "session's estimate", png)]


def _figures(obj: Any) -> dict[str, Any]:
    """The checked figures of a section, by name (those not checked left out)."""
    return {f.name: list(v) if isinstance(v, tuple) else v
            for f in fields(obj) if (v := getattr(obj, f.name)) is not None}


def checks_section(r: CalibrationResult) -> Section:
    """Plausibility verdict, segment consistency, sensitivity to the noise densities."""
    pl = r.plausibility
    blocks: list[Any] = [Notes("checks-lines", checks_lines(r) or ["no checks recorded"])]
    if pl is not None and pl.failed:
        blocks.append(Notes("plausibility-failed", [f"FAILED: {x}" for x in pl.failed],
                            "warning"))
    row: list[Any] = []
    if pl is not None:
        rows = [["verdict", num("plausibility/verdict", pl.verdict)]]
        rows += kv_rows(_figures(pl.figures), "plausibility/figures")
        row.append(Table("plausibility-table", ("check", "value"), rows,
                         "Plausibility: physical checks"))
    cons = _consistency_blocks(r)
    row += [b for b in cons if isinstance(b, Table) and b.id == "consistency-summary"]
    sens = _sensitivity_table(r)
    if sens is not None:
        row.append(sens)
    unc = _uncertainty_table(r)
    if unc is not None:
        row.append(unc)
    blocks.append(Row(row))
    blocks += [b for b in cons if not (isinstance(b, Table) and b.id == "consistency-summary")]
    return Section("sec-checks", "Checks: plausibility, consistency, sensitivity", blocks)


def _uncertainty_table(r: CalibrationResult) -> Table | None:
    """Per compared parameter and axis, every term of the reported sigma (the rule in
    core/checks/verdict.py), so that a reader sees which one dominates."""
    rows: list[list[str | Cell]] = []
    for p in COMPARED:
        u = r.estimate(p).terms
        if u is None:
            continue
        unit, k, key = p.printed.sigma_unit, p.printed.sigma_scale, p.symbol
        n = len(u.total)
        for a in range(n):
            rows.append([f"{key} ({unit})" if a == 0 else "", "xyz"[a] if n > 1 else ""]
                        + [num(f"uncertainty/{key}/{t}/{a}", float(getattr(u, t)[a]), k,
                               digits=3)
                           if getattr(u, t) is not None else "-" for t, _ in UNCERTAINTY_TERMS]
                        + [num(f"uncertainty/{key}/consistency_factor",
                               u.consistency_factor, digits=3) if a == 0 else ""])
    if not rows:
        return None
    head = ["parameter", "axis", *(label for _, label in UNCERTAINTY_TERMS),
            "consistency factor"]
    return Table("uncertainty-table", head, rows, "Sigma: the terms of the rule "
                 "(total = max(sqrt((factor x statistical)^2 + shifts^2), largest move))")


def _sensitivity_table(r: CalibrationResult) -> Table | None:
    """Per parameter, how many sigmas it moves under each scaling of the noise densities
    (total and statistical sigmas)."""
    sens = r.sensitivity
    if sens is None:
        return None
    groups = (("moved_sigmas", sens.moved or {}),
              ("moved_statistical_sigmas", sens.moved_statistical))
    cols = [(what, f, m) for what, by in groups for f, m in by.items()]
    if not cols:
        return None
    params = list(dict.fromkeys(p for _, _, m in cols for p in m))
    rows: list[list[str | Cell]] = []
    for p in params:
        rows.append([p.symbol] + [num(f"sensitivity/{what}/{f}/{p.symbol}", m[p], digits=3)
                                  if p in m else "" for what, f, m in cols])
    head = ["parameter"] + [f"{f} ({'total' if what == 'moved_sigmas' else 'statistical'})"
                            for what, f, _ in cols]
    return Table("sensitivity-table", head, rows, "Sensitivity: sigmas moved when the IMU "
                 "noise densities are scaled")


def clock_section(r: CalibrationResult, cs: ClockCurve | None = None) -> Section:
    """The coarse clock search: curve (``cs``, None: not drawn), chosen peak, margin and the
    fine estimate."""
    c = r.clock
    if c is None:
        return Section("sec-clock", "Clock search", ["No search: the clock offset was given."])
    figures = [("coarse_time_offset", c.time_offset), ("peak_z", c.peak_z),
               ("margin_z", c.margin_z), ("second_best_time_offset", c.second_offset)]
    if c.fine_time_offset is not None:
        figures.append(("fine_time_offset", c.fine_time_offset))
    rows = [[k, num(f"clock/{k}", v, digits=8 if "offset" in k else 4)] for k, v in figures]
    rows += [[f"candidate {i + 1}", Cell(f"t_d {t:.6g} s, z {z:.4g}")]
             for i, (t, z) in enumerate(c.candidates)]
    rows.append(["signals", ", ".join(c.signals)])
    blocks: list[Any] = [Table("clock-table", ("figure", "value"), rows, "Clock search")]
    if cs is not None and len(cs.lags):
        fine = c.fine_time_offset
        png = plots.clock_png(cs.lags, cs.score, cs.time_offset, cs.candidates, cs.peak_z,
                              cs.margin_z, fine, cs.min_peak_z)
        blocks.append(Figure(
            "fig-clock", f"Clock search: combined correlation statistic against t_d; chosen "
            f"peak {1e3 * cs.time_offset:.3f} ms at {cs.peak_z:.2f} null sigmas, margin "
            f"{cs.margin_z:.2f} over the next peak; fine estimate "
            + ("-" if fine is None else f"{1e3 * fine:.3f} ms"), png,
            data={"peak-z": f"{c.peak_z!r}", "margin-z": f"{c.margin_z!r}",
                  "coarse-time-offset": f"{c.time_offset!r}",
                  "fine-time-offset": f"{fine!r}"}))
    return Section("sec-clock", "Clock search", blocks)
