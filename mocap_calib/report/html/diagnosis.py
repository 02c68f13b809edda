"""Diagnosis report sections: the residual gap per step and sensor, every candidate's test
statistic, and the ``unexplained`` signature when the diagnosis reports one."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from mocap_calib.report.html.mpl import log_axes, new_figure, styled, to_png
from mocap_calib.report.html.page import Cell, Figure, Notes, Section, Table
from mocap_calib.report.html.tables import kv_rows, num

if TYPE_CHECKING:
    from mocap_calib.core.diagnosis.diagnose import DiagnoseReport


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


def _numbers(d: Any) -> dict[str, float] | None:
    if isinstance(d, Mapping) and d and all(isinstance(v, (int, float)) and not
                                            isinstance(v, bool) for v in d.values()):
        return {str(k): float(v) for k, v in d.items()}
    return None


def _offsets(v: Any) -> list[float] | None:
    if isinstance(v, (list, tuple)) and v:
        if all(isinstance(x, (int, float)) for x in v):
            return [float(x) for x in v]
        if all(isinstance(x, Mapping) for x in v):
            keys = [k for k in v[0] if "offset" in str(k) and isinstance(v[0][k], (int, float))]
            if keys:
                return [float(x[keys[0]]) for x in v]
    return None


def unexplained_png(u: Mapping[str, Any]) -> bytes | None:
    """Correlations of the unexplained residual (bars) and per-segment clock offsets."""
    corr = next(((k, c) for k, v in u.items() if "corr" in str(k)
                 and (c := _numbers(v)) is not None), None)
    offs = next(((k, o) for k, v in u.items() if ("offset" in str(k) or "clock" in str(k))
                 and (o := _offsets(v)) is not None), None)
    if corr is None and offs is None:
        return None
    with styled():
        fig = new_figure(9.5, 2.6, left=0.08, bottom=0.3, wspace=0.3)
        axes = fig.subplots(1, 2)
        if corr is not None:
            k, c = corr
            axes[0].bar(range(len(c)), list(c.values()), color="#1f77b4")
            axes[0].set_xticks(range(len(c)), list(c), rotation=15, ha="right", fontsize=7)
            axes[0].axhline(0.0, color="k", lw=0.6)
            axes[0].set_title(k, y=1.0)
        if offs is not None:
            k, o = offs
            axes[1].plot(np.arange(1, len(o) + 1), 1e3 * np.asarray(o), "o-", color="#444")
            axes[1].set_xlabel("segment")
            axes[1].set_ylabel("ms")
            axes[1].set_title(k, y=1.0)
        return to_png(fig)


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
            rows.append([str(i + 1) if j == 0 else "", c["effect"], num(f"{p}/dof", c["dof"]),
                         num(f"{p}/statistic", c["statistic"], digits=6),
                         num(f"{p}/log10_p", c["log10_p"], digits=5),
                         num(f"{p}/noise_scale", c["noise_scale"], digits=4),
                         num(f"{p}/residual_drop", c["residual_drop"], digits=4),
                         num(f"{p}/significant", c["significant"])])
    return rows


def unexplained_of(report: Any) -> Mapping[str, Any] | None:
    """The report's ``unexplained`` signature (attribute or to_dict key), if any."""
    u = getattr(report, "unexplained", None)
    if u is None:
        u = report.to_dict().get("unexplained") if hasattr(report, "to_dict") else None
    if u is not None and hasattr(u, "to_dict"):
        u = u.to_dict()
    return u if isinstance(u, Mapping) and u else None


def diagnosis_steps_sections(report: DiagnoseReport) -> list[Section]:
    """Verdict, steps (gap per sensor, candidates) and the unexplained signature."""
    d = report.to_dict()
    steps = d["steps"]
    thr = float(d["test"]["threshold_log10_p"])
    labels = [s["model"] for s in steps]
    blocks: list[Any] = [
        Notes("diagnosis-verdict", [f"verdict: {d['verdict']} (found: "
                                    f"{', '.join(d['found']) or 'nothing'}); start model "
                                    f"{d['start_model']}, final model {d['final_model']}"],
              "ok" if not d["found"] else "warning"),
        Table("diagnosis-steps", ("step", "model", "gyro RMS / floor", "accel RMS / floor",
                                  "chi2", "dof", "added", "best candidate"), _step_rows(steps),
              "The gap per sensor at every step (low-band residual over the noise floor)"),
        Figure("fig-diagnose-gap", "Residual over noise floor per sensor after each step "
               "(1 = at the noise floor); the effect added at each step is named",
               gap_png(labels, [s["residuals"]["gyro_ratio"] for s in steps],
                       [s["residuals"]["accel_ratio"] for s in steps],
                       [(s.get("added") or {}).get("effect") for s in steps]),
               data={"steps": str(len(steps)), "threshold-log10-p": f"{thr!r}"}),
        Table("diagnosis-candidates", ("step", "candidate", "dof", "statistic T", "log10 p",
                                       "noise scale", "residual drop", "significant"),
              _candidate_rows(steps), f"Every candidate's likelihood-ratio test (threshold "
              f"log10 p < {thr:.3f}, Bonferroni over the candidates)"),
    ]
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
            ub.append(Figure("fig-unexplained", "Unexplained residual: its correlations with "
                             "angular rate, angular acceleration and specific force, and the "
                             "clock offset per segment", png))
        out.append(Section("sec-unexplained", "Unexplained residual", ub))
    return out
