"""Fleet summary: per IMU id, the history of every calibrated block over dates, its
first-order trend, and the sessions that disagree with the rest of their history.

The trend is the one ``--prior`` extrapolates (:func:`priors_from_results`: a weighted straight
line per tangent component around the latest result, its scatter-inflated sigma); evaluated at
the latest date and one day either side it gives the value, the slope per day and their sigmas.
A session is an outlier in a block when it differs from the trend of the *other* sessions of
its IMU, at its own date, by more than ``OUTLIER_SIGMAS`` combined sigmas in some component.

Files: ``history.csv`` (one row per session), ``trends.csv`` (one row per IMU, block and
component) and ``fleet.yaml`` (all of it, with the outliers listed).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.batch.manifest import SessionEntry
from mocap_calib.core.model.parameters import PARAMETERS
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.priors import priors_from_results, to_chart
from mocap_calib.core.versioned import header
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import save_yaml

FLEET_KIND, FLEET_VERSION = "fleet", 1
OUTLIER_SIGMAS = 4.0
DAY_NS = 86_400 * 1_000_000_000
#: Units of each block's tangent components (rates are these per day).
UNITS = {p.name: p.unit for p in PARAMETERS.values()}


def _dated(r: CalibrationResult, time_ns: int) -> CalibrationResult:
    """The result placed at its manifest date (IMU clocks often count from power-up)."""
    return replace(r, session={**r.session, "imu_start_ns": int(time_ns)}, diagnostics=None)


def _blocks(r: CalibrationResult) -> dict[str, Any]:
    """Every block the result determined, as a prior: value (natural form) and tangent sigma."""
    return {p.block: p for p in priors_from_results([r], None, session_specific=True)}


def _line(rs: list[CalibrationResult], at_ns: int) -> dict[str, Any]:
    """The trend of ``rs`` (two dates or more) at ``at_ns``, per block."""
    return {p.block: p for p in priors_from_results(rs, at_ns, session_specific=True)}


def _natural(block: str, value: Any) -> list[float]:
    p = PARAMETERS.get(block)  # as the result files write it (a rotation as a quaternion)
    return [float(v) for v in (np.atleast_1d(np.asarray(value, dtype=float)) if p is None
                               else p.value_of(value))]


def trends(rs: list[CalibrationResult]) -> dict[str, dict[str, Any]]:
    """Per block: value and sigma at the latest date, slope and its sigma per day (tangent
    components around the latest value). Empty with fewer than two dates."""
    times = [int(r.session["imu_start_ns"]) for r in rs]
    if len(set(times)) < 2:
        return {}
    t = max(times)
    ref = _blocks(max(zip(times, range(len(rs)), rs, strict=True))[2])
    now, ahead, back = _line(rs, t), _line(rs, t + DAY_NS), _line(rs, t - DAY_NS)
    out = {}
    for block, p0 in now.items():
        if block not in ref or block not in ahead or block not in back:
            continue
        r0 = ref[block].value
        xp = to_chart(block, ahead[block].value, r0)
        xm = to_chart(block, back[block].value, r0)
        # sigma^2(t) = var_a + 2 cov_ab t + var_b t^2: its second difference gives var_b.
        var_b = (ahead[block].sigma ** 2 + back[block].sigma ** 2 - 2 * p0.sigma ** 2) / 2.0
        out[block] = {
            "unit": UNITS.get(block, "parameter"),
            "value": _natural(block, p0.value),
            "sigma": [float(s) for s in p0.sigma],
            "slope_per_day": [float(v) for v in (xp - xm) / 2.0],
            "sigma_slope_per_day": [float(v) for v in np.sqrt(np.maximum(var_b, 0.0))],
        }
    return out


def outlier_z(rs: list[CalibrationResult], k: int) -> dict[str, float]:
    """Per block, the largest |difference| / combined sigma of session ``k`` against the trend
    of the other sessions at its date (their value, with one other session)."""
    others = [r for i, r in enumerate(rs) if i != k]
    if not others:
        return {}
    t_k = int(rs[k].session["imu_start_ns"])
    if len({int(r.session["imu_start_ns"]) for r in others}) >= 2:
        expected = _line(others, t_k)
    else:
        expected = _blocks(others[-1])
    z = {}
    for block, own in _blocks(rs[k]).items():
        e = expected.get(block)
        if e is None:
            continue
        # In the tangent space at the expected value (for plain vectors the chart is the
        # identity, so subtract its own image).
        d = to_chart(block, own.value, e.value) - to_chart(block, e.value, e.value)
        s = np.sqrt(np.asarray(own.sigma) ** 2 + np.asarray(e.sigma) ** 2)
        z[block] = float(np.max(np.abs(d) / np.maximum(s, 1e-300)))
    return z


def _row(entry: SessionEntry, r: CalibrationResult, z: dict[str, float]) -> dict[str, Any]:
    row: dict[str, Any] = {"imu_id": entry.imu_id, "id": entry.id, "date": entry.date}
    for p in PARAMETERS.values():
        for name, vals in ((p.value_key[-1], r.value(p)), (f"sigma_{p.name}", r.sigma(p))):
            flat = [] if vals is None else np.atleast_1d(np.asarray(vals, dtype=float)).ravel()
            if len(flat) == 1:
                row[name] = float(flat[0])
            for i, v in enumerate(flat if len(flat) > 1 else []):
                row[f"{name}_{'wxyz'[i] if len(flat) == 4 else i}"] = float(v)
    for eff, rec in sorted(r.effects.items()):
        for key, val in rec.items():
            flat = np.atleast_1d(np.asarray(val, dtype=float)).ravel()
            for i, v in enumerate(flat):
                row[f"{eff}.{key}" + (f"_{i}" if len(flat) > 1 else "")] = float(v)
    for block, zb in z.items():
        row[f"z_{block}"] = round(zb, 3)
    row["outlier"] = "+".join(b for b, zb in z.items() if zb > OUTLIER_SIGMAS)
    return row


def fleet_summary(done: Sequence[tuple[SessionEntry, CalibrationResult]]
                  ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """History rows (one per session) and the per-IMU summary of trends and outliers."""
    rows: list[dict[str, Any]] = []
    imus: dict[str, Any] = {}
    for imu_id in sorted({e.imu_id for e, _ in done}):
        group = sorted(((e, r) for e, r in done if e.imu_id == imu_id),
                       key=lambda er: (er[0].time_ns, er[0].id))
        rs = [_dated(r, e.time_ns) for e, r in group]
        outliers = []
        for k, (entry, r) in enumerate(group):
            z = outlier_z(rs, k)
            rows.append(_row(entry, r, z))
            outliers += [{"id": entry.id, "date": entry.date, "block": b, "z": round(zb, 2)}
                         for b, zb in z.items() if zb > OUTLIER_SIGMAS]
        imus[imu_id] = {
            "sessions": [{"id": e.id, "date": e.date} for e, _ in group],
            "latest_date": group[-1][0].date,
            "trends": trends(rs),
            "outliers": outliers,
        }
    summary = {**header(FLEET_KIND, FLEET_VERSION), "outlier_sigmas": OUTLIER_SIGMAS,
               "trend": "weighted straight line per tangent component over the manifest dates "
                        "(as --prior extrapolates); value at latest_date, slopes per day",
               "imus": imus}
    return rows, summary


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    names: list[str] = []
    for row in rows:
        names += [k for k in row if k not in names]

    def write(p: Path) -> None:
        with p.open("x", newline="") as f:
            w = csv.DictWriter(f, fieldnames=names)
            w.writeheader()
            w.writerows(rows)
    return write_with(path, write)


def write_fleet(folder: Path, done: Sequence[tuple[SessionEntry, CalibrationResult]]
                ) -> tuple[list[Path], list[dict[str, Any]]]:
    """Write ``history.csv``, ``trends.csv`` and ``fleet.yaml`` into ``folder``; return the
    files and the outliers (``imu_id``, ``id``, ``date``, ``block``, ``z``)."""
    if not done:
        return [], []
    rows, summary = fleet_summary(done)
    trend_rows = [{"imu_id": imu, "block": block, "component": c, "unit": tr["unit"],
                   "sigma": tr["sigma"][c], "slope_per_day": tr["slope_per_day"][c],
                   "sigma_slope_per_day": tr["sigma_slope_per_day"][c]}
                  for imu, rec in summary["imus"].items()
                  for block, tr in rec["trends"].items() for c in range(len(tr["sigma"]))]
    files = [_write_csv(folder / "history.csv", rows)]
    if trend_rows:
        files.append(_write_csv(folder / "trends.csv", trend_rows))
    files.append(save_yaml(folder / "fleet.yaml", summary, "mocap-calib fleet summary: "
                           "history, trends and outliers per IMU"))
    outliers = [{"imu_id": imu, **o} for imu, rec in summary["imus"].items()
                for o in rec["outliers"]]
    return files, outliers
