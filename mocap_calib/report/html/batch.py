"""Batch report sections: one row per session, the estimates over the sessions' dates per IMU,
the fleet's outliers, then each session's result and checks."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from mocap_calib.core.model.parameters import TRANSLATION
from mocap_calib.report.html.mpl import AXIS_COLORS, new_figure, styled, to_png
from mocap_calib.report.html.page import Cell, Figure, Notes, Section, Table

if TYPE_CHECKING:
    from mocap_calib.core.result.calibration import CalibrationResult


def _fmt(v: float | None, k: float = 1.0, digits: int = 5) -> str:
    return "-" if v is None else f"{float(v) * k:.{digits}g}"


def trends_png(groups: Mapping[str, list[tuple[str, CalibrationResult]]]) -> bytes:
    """t_d and p_MI per session (in date order) with 1-sigma bars, one colour set per IMU."""
    with styled():
        fig = new_figure(9.5, 2.8, left=0.07, bottom=0.3, wspace=0.22)
        a1, a2 = fig.subplots(1, 2)
        x0 = 0
        ticks: list[str] = []
        for imu, rows in groups.items():
            x = np.arange(x0, x0 + len(rows))
            td = [np.nan if r.time_offset is None else 1e3 * r.time_offset for _, r in rows]
            sd = [0.0 if r.sigma_time_offset is None else 1e3 * r.sigma_time_offset
                  for _, r in rows]
            a1.errorbar(x, td, yerr=sd, fmt="o", ms=3, capsize=3, label=imu)
            for i in range(3):
                p = [np.nan if r.translation is None else 1e3 * r.translation[i] for _, r in rows]
                s = [0.0 if r.sigma(TRANSLATION) is None else 1e3 * r.sigma(TRANSLATION)[i]
                     for _, r in rows]
                a2.errorbar(x, p, yerr=s, fmt="o", ms=3, capsize=3, color=AXIS_COLORS[i],
                            label="xyz"[i] if x0 == 0 else None)
            ticks += [f"{imu}:{d}" for d, _ in rows]
            x0 += len(rows)
        for ax in (a1, a2):
            ax.set_xticks(range(len(ticks)), ticks, rotation=30, ha="right", fontsize=6.5)
        a1.set_title("t_d per session (ms)", y=1.0)
        a2.set_title("p_MI per session (mm)", y=1.0)
        a1.legend(loc="best", fontsize=6.5)
        a2.legend(loc="best", ncols=3)
        return to_png(fig)


def _summary_rows(sessions: Sequence[Mapping[str, Any]],
                  results: Mapping[str, CalibrationResult]) -> list[list[str | Cell]]:
    rows: list[list[str | Cell]] = []
    for s in sessions:
        r = results.get(str(s.get("id")))
        verdict = "-" if r is None or r.plausibility is None else r.plausibility.verdict
        td = "-" if r is None or r.time_offset is None else (
            f"{1e3 * r.time_offset:.3f} ± {_fmt(r.sigma_time_offset, 1e3, 2)}")
        p = "-" if r is None or r.translation is None else ", ".join(
            f"{1e3 * x:.2f}" for x in r.translation)
        rows.append([str(s.get("id")), str(s.get("imu_id", "")), str(s.get("date", "")),
                     str(s.get("status", "")), _fmt(s.get("seconds"), digits=4), td, p,
                     verdict, str(s.get("error", ""))])
    return rows


def _fleet_notes(fleet: Mapping[str, Any] | None) -> list[str]:
    if not fleet:
        return ["no fleet summary (no session succeeded)"]
    out = []
    for imu, d in (fleet.get("imus") or {}).items():
        outliers = d.get("outliers") or []
        out.append(f"IMU {imu}: {len(d.get('sessions') or [])} sessions, latest "
                   f"{d.get('latest_date')}; "
                   + ("no outliers" if not outliers else "outliers: " + "; ".join(
                       f"{o.get('id')} {o.get('block')} z {o.get('z')}" for o in outliers)))
    return out


def batch_report_sections(sessions: Sequence[Mapping[str, Any]],
                          results: Mapping[str, CalibrationResult],
                          fleet: Mapping[str, Any] | None) -> list[Section]:
    """Sections of a batch page (see :func:`mocap_calib.report.html.batch_sections`)."""
    from mocap_calib.report.html.calibration import checks_section, result_section
    from mocap_calib.report.html.page import prefixed

    n_ok = sum(1 for s in sessions if str(s.get("id")) in results)
    blocks: list[Any] = [
        Table("batch-table", ("session", "IMU", "date", "status", "seconds", "t_d (ms) ± 1-sigma",
                              "p_MI (mm)", "plausibility", "error"),
              _summary_rows(sessions, results),
              f"{len(sessions)} sessions, {n_ok} with a result"),
        Notes("fleet-notes", _fleet_notes(fleet),
              "warning" if fleet and any((d.get("outliers") or [])
                                         for d in (fleet.get("imus") or {}).values()) else "ok"),
    ]
    groups: dict[str, list[tuple[str, CalibrationResult]]] = {}
    for s in sessions:
        r = results.get(str(s.get("id")))
        if r is not None:
            groups.setdefault(str(s.get("imu_id", "")), []).append((str(s.get("date", "")), r))
    if groups:
        for g in groups.values():
            g.sort(key=lambda dr: dr[0])
        blocks.append(Figure("fig-batch-trends", "t_d and p_MI of every session with 1-sigma, "
                             "per IMU in date order", trends_png(groups),
                             data={"sessions": str(n_ok)}))
    out = [Section("sec-batch", "Batch: every session", blocks)]
    for i, s in enumerate(sessions):
        r = results.get(str(s.get("id")))
        if r is None:
            continue
        for sec in prefixed([result_section(r), checks_section(r)], f"s{i}-"):
            sec.title = f"{s.get('id')}: {sec.title}"
            out.append(sec)
    return out
