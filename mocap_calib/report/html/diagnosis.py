"""Diagnosis report sections: the residual gap per step and sensor, every candidate's test
statistic, and the ``unexplained`` signature when the diagnosis reports one."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from mocap_calib.report.html.mpl import log_axes, new_figure, styled, to_png
from mocap_calib.report.html.page import Cell, Figure, Notes, Section, Table
from mocap_calib.report.html.tables import kv_rows, num

if TYPE_CHECKING:
    from mocap_calib.core.result.calibration import CalibrationResult


class DiagnosisRecord(Protocol):
    """What the diagnosis pages read of a diagnosis report
    (``core.diagnosis.report.DiagnoseReport``): its file form, its notes and its final
    calibration."""

    notes: list[str]
    final: CalibrationResult

    def to_dict(self) -> dict[str, Any]: ...


def gap_png(labels: list[str], gyro: list[float], accel: list[float],
            added: list[str | None]) -> bytes:
    """Residual / noise floor per sensor after each step (1 = at the floor)."""
    with styled():
        fig = new_figure(9.5, 2.8, left=0.07, bottom=0.3, top=0.9)
        ax = fig.add_subplot()
        x = np.arange(len(labels))
        ax.plot(x, gyro, "o-", color="#1f77b4", label="gyro")
        ax.plot(x, accel, "s-", color="#d62728", label="accel")
        ax.axhline(1.0, color="k", ls="--", lw=0.8, label="noise floor")
        for i, a in enumerate(added):
            if a:
                ax.annotate(f"+{a}", (i + 0.5, max(gyro[i], accel[i])), ha="center",
                            fontsize=7.5, color="#2ca02c")
        ax.set_xticks(x, labels, rotation=12, ha="right", fontsize=7)
        vals = [v for v in gyro + accel if v > 0]
        if vals and max(vals) / min(vals) > 20.0:
            log_axes(ax, x=False)
        ax.set_ylim(bottom=0.0 if ax.get_yscale() == "linear" else None)
        ax.set_ylabel("low-band RMS / floor")
        ax.set_title("the gap to the noise floor, step by step", y=1.0)
        ax.legend(loc="upper right")
        return to_png(fig)


def candidates_png(steps: list[dict[str, Any]], threshold: float) -> bytes:
    """Per step: -log10 p of every candidate, the threshold, the one added."""
    tested = [s for s in steps if s.get("candidates")]
    n = max(1, len(tested))
    with styled():
        fig = new_figure(9.5, 0.6 + 0.28 * max(len(s["candidates"]) for s in tested)
                         if tested else 2.0, left=0.2, bottom=0.18, wspace=0.6, top=0.88)
        axes = np.atleast_1d(fig.subplots(1, n, sharex=False))
        for ax, (i, s) in zip(axes, enumerate(tested), strict=False):
            c = s["candidates"]
            names = [x["effect"] for x in c]
            v = [min(-float(x["log10_p"]), 400.0) for x in c]
            added = (s.get("added") or {}).get("effect")
            colors = ["#2ca02c" if nm == added else ("#ff7f0e" if x["significant"] else "#999")
                      for nm, x in zip(names, c, strict=True)]
            y = np.arange(len(c))[::-1]
            ax.barh(y, np.maximum(v, 1e-3), color=colors)
            ax.set_yticks(y, names, fontsize=7)
            ax.axvline(-threshold, color="k", ls="--", lw=0.8)
            ax.set_xscale("symlog", linthresh=1.0)
            ax.set_title(f"step {i + 1}: {s['model']}", y=1.0, fontsize=7.5)
            ax.set_xlabel("-log10 p")
        return to_png(fig)


SIGNALS = ("angular_rate", "angular_acceleration", "specific_force")
SHORT = {"angular_rate": "rate", "angular_acceleration": "ang. acc.", "specific_force": "force"}


def _corr_panel(ax: Any, u: Mapping[str, Any]) -> bool:
    """Grouped bars: the strongest axis correlation and the magnitude correlation of each
    sensor's residual with each signal."""
    bars = []
    for sensor in ("gyro", "accel"):
        corr = (u.get(sensor) or {}).get("correlation") or {}
        for sig in SIGNALS:
            c = corr.get(sig) or {}
            if "max_abs_corr" in c:
                bars.append((f"{sensor}\n{SHORT[sig]}", float(c["max_abs_corr"]),
                             float(c.get("magnitude_corr", np.nan)),
                             f"{c.get('residual_axis', '')}~{c.get('signal_axis', '')}"))
    if not bars:
        return False
    x = np.arange(len(bars))
    ax.bar(x - 0.2, [b[1] for b in bars], 0.4, color="#1f77b4", label="strongest axis pair")
    ax.bar(x + 0.2, [b[2] for b in bars], 0.4, color="#ff7f0e", label="magnitudes")
    for xi, b in zip(x, bars, strict=True):
        ax.annotate(b[3], (xi - 0.2, b[1]), ha="center", va="bottom", fontsize=6.5)
    ax.set_xticks(x, [b[0] for b in bars], fontsize=6.5)
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_ylim(-1.05, 1.15)
    ax.set_title("correlation of the residual with", y=1.0)
    ax.legend(loc="lower left", fontsize=6.5)
    return True


def _clock_panel(ax: Any, c: Mapping[str, Any]) -> bool:
    if not c.get("t_s"):
        ax.text(0.5, 0.5, str(c.get("note", "no clock profile")), ha="center", va="center",
                transform=ax.transAxes, fontsize=7, wrap=True)
        ax.set_axis_off()
        return False
    ax.errorbar(c["t_s"], c["t_d_ms"], yerr=c.get("sigma_ms"), fmt="o-", ms=3, capsize=3,
                color="#444")
    ax.set_xlabel("segment middle (s)")
    ax.set_title(f"t_d per segment (ms)\nslope {c.get('slope_ppm', 0):g} ppm, largest jump "
                 f"{c.get('largest_jump_sigmas', 0):g} sigma", y=1.0, fontsize=7.5)
    return True


def unexplained_png(u: Mapping[str, Any]) -> bytes | None:
    """Correlations with rate, angular acceleration and specific force; residual RMS per
    time segment; clock offset per segment."""
    with styled():
        fig = new_figure(9.5, 3.0, left=0.05, right=0.99, bottom=0.2, top=0.86, wspace=0.25)
        a1, a2, a3 = fig.subplots(1, 3, width_ratios=[2.2, 1, 1.2])
        drew = _corr_panel(a1, u)
        for sensor, color in (("gyro", "#1f77b4"), ("accel", "#d62728")):
            seg = (u.get(sensor) or {}).get("rms_per_time_segment") or []
            if seg:
                a2.plot(np.arange(1, len(seg) + 1), seg, "o-", color=color, ms=3, label=sensor)
                drew = True
        a2.axhline(1.0, color="k", lw=0.6)
        a2.set_xlabel("time segment")
        a2.set_title("residual RMS per segment\nover the overall RMS", y=1.0, fontsize=7.5)
        a2.legend(loc="best", fontsize=6.5)
        drew = _clock_panel(a3, u.get("clock_offset_per_segment") or {}) or drew
        return to_png(fig) if drew else None


def _step_rows(steps: list[dict[str, Any]]) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for i, s in enumerate(steps):
        p = f"steps/{i}"
        best = (s.get("candidates") or [{}])[0]
        rows.append([str(i), s["model"],
                     num(f"{p}/residuals/gyro_ratio", s["residuals"]["gyro_ratio"], digits=4),
                     num(f"{p}/residuals/accel_ratio", s["residuals"]["accel_ratio"], digits=4),
                     num(f"{p}/chi2", s["chi2"], digits=8), num(f"{p}/dof", s["dof"]),
                     (s.get("added") or {}).get("effect") or "-",
                     best.get("effect", "-")])
    return rows


def _candidate_rows(steps: list[dict[str, Any]]) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for i, s in enumerate(steps):
        for j, c in enumerate(s.get("candidates") or []):
            p = f"steps/{i}/candidates/{j}"
            refit = c.get("refit") or {}
            why = c.get("implausible") or c.get("refuted")
            rows.append([str(i + 1) if j == 0 else "", c["effect"], num(f"{p}/dof", c["dof"]),
                         num(f"{p}/statistic", c["statistic"], digits=6),
                         num(f"{p}/log10_p", c["log10_p"], digits=5),
                         num(f"{p}/refit/log10_p", refit["log10_p"], digits=5) if refit
                         else "-",
                         num(f"{p}/refit/residual_drop", refit.get("residual_drop"), digits=4)
                         if refit else "-",
                         num(f"{p}/significant", c["significant"]),
                         num(f"{p}/{'implausible' if c.get('implausible') else 'refuted'}",
                             why) if why else ""])
    return rows


def _value(key: str, v: Any, digits: int) -> str | Cell:
    """A scalar as a keyed cell; a vector or matrix (or a mapping of them) as plain text."""
    if v is None or isinstance(v, (int, float)):
        return num(key, v, digits=digits)
    return str(np.round(np.asarray(v, dtype=float), 6).tolist()) if not isinstance(v, dict) \
        else ", ".join(f"{k} {np.round(np.asarray(x, dtype=float), 6).tolist()}"
                       for k, x in v.items())


def _take_rows(steps: list[dict[str, Any]]) -> list[list[str | Cell]]:
    """Per effect added, each take's own estimate and test (several takes only)."""
    rows: list[list[str | Cell]] = []
    for i, s in enumerate(steps):
        added = s.get("added") or {}
        for j, t in enumerate(added.get("takes") or []):
            p = f"steps/{i}/added/takes/{j}"
            rows.append([str(i + 1) if j == 0 else "", added["effect"] if j == 0 else "",
                         num(f"{p}/take", t["take"]), _value(f"{p}/value", t["value"], 4),
                         _value(f"{p}/sigma", t["sigma"], 2),
                         num(f"{p}/log10_p", t["log10_p"], digits=5),
                         num(f"{p}/evidence", t["evidence"])])
    return rows


def unexplained_of(report: Any) -> Mapping[str, Any] | None:
    """The report's ``unexplained`` signature (attribute or to_dict key), if any."""
    u = getattr(report, "unexplained", None)
    if u is None:
        u = report.to_dict().get("unexplained") if hasattr(report, "to_dict") else None
    if u is not None and hasattr(u, "to_dict"):
        u = u.to_dict()
    return u if isinstance(u, Mapping) and u else None


def diagnosis_steps_sections(report: DiagnosisRecord) -> list[Section]:
    """Verdict, steps (gap per sensor, candidates) and the unexplained signature."""
    d = report.to_dict()
    steps = d["steps"]
    thr = float(d["test"]["threshold_log10_p"])
    labels = [s["model"] for s in steps]
    blocks: list[Any] = [
        Notes("diagnosis-verdict", [f"verdict: {d['verdict']} (found: "
                                    f"{', '.join(d['found']) or 'nothing'}); start model "
                                    f"{d['start_model']}, final model {d['final_model']}"]
              + [f"implausible: {x}" for x in d.get("implausible") or []],
              "ok" if not d["found"] and not d.get("unexplained") else "warning"),
        Table("diagnosis-steps", ("step", "model", "gyro RMS / floor", "accel RMS / floor",
                                  "chi2", "dof", "added", "best candidate"), _step_rows(steps),
              "The gap per sensor at every step (low-band residual over the noise floor)"),
        Figure("fig-diagnose-gap", "Residual over noise floor per sensor after each step "
               "(1 = at the noise floor); the effect added at each step is named",
               gap_png(labels, [s["residuals"]["gyro_ratio"] for s in steps],
                       [s["residuals"]["accel_ratio"] for s in steps],
                       [(s.get("added") or {}).get("effect") for s in steps]),
               data={"steps": str(len(steps)), "threshold-log10-p": f"{thr!r}"}),
        Table("diagnosis-candidates", ("step", "candidate", "dof", "score T", "log10 p",
                                       "refit log10 p", "residual drop", "significant",
                                       "not added because"),
              _candidate_rows(steps), f"Every candidate's score test at the step's solution "
              f"(threshold log10 p < {thr:.3f}, Bonferroni over the candidates); the "
              "significant ones refitted until one is confirmed"),
    ]
    take_rows = _take_rows(steps)
    if take_rows:
        blocks.append(Table("diagnosis-takes", ("step", "effect", "take", "estimate",
                                                "1-sigma", "log10 p alone", "evidence"),
                            take_rows, "Several takes: each effect found, refitted in each "
                            "take alone from the joint solution; evidence: that take's own "
                            f"test passes the threshold (log10 p < {thr:.3f})"))
    if any(s.get("candidates") for s in steps):
        blocks.append(Figure("fig-diagnose-candidates", "Each candidate's -log10 p per step; "
                             "dashed: the threshold; green: added, orange: significant",
                             candidates_png(steps, thr)))
    if report.notes:
        blocks.append(Notes("diagnosis-notes", list(report.notes), "warning"))
    out = [Section("sec-diagnosis", "Diagnosis: what the model misses", blocks)]
    u = unexplained_of(report)
    if u is not None:
        ub: list[Any] = [Table("unexplained-table", ("figure", "value"),
                               kv_rows(u, "unexplained"),
                               "Signature of the residual no candidate explains")]
        png = unexplained_png(u)
        if png is not None:
            where = "; ".join(f"{k}: axes {', '.join(v.get('axes_over_floor') or []) or '-'}, "
                              f"band {v.get('band_most_over_floor')}"
                              for k, v in u.items() if isinstance(v, Mapping)
                              and "axes_over_floor" in v)
            ub.append(Figure("fig-unexplained", "Unexplained residual (" + where + "): its "
                             "correlations with angular rate, angular acceleration and "
                             "specific force, its RMS per time segment, and the clock offset "
                             "per segment", png))
        out.append(Section("sec-unexplained", "Unexplained residual", ub))
    return out
