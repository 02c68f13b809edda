"""Readable text summaries of a calibration result (terminal, recordings, reports)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.parameters import (
    COMPARED,
    PARAMETERS,
    PER_TAKE,
    TIME_OFFSET,
    Parameter,
)
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.estimate import SigmaTerms

Array = NDArray[np.float64]


def _fmt(v: object, scale: float = 1.0, digits: int = 4) -> str:
    """A number, a vector or a matrix (flattened) on one line; a mapping of those (an effect
    with several parameters, e.g. ``{r_y: [..], r_z: [..]}``) as ``key value`` pairs."""
    if v is None:
        return "unobservable"
    if isinstance(v, dict):
        return ", ".join(f"{k} {_fmt(x, scale, digits)}" for k, x in v.items())
    a = np.atleast_1d(np.asarray(v, dtype=float)).ravel() * scale
    if a.size == 1:
        return f"{a[0]:.{digits}g}"
    return "[" + ", ".join(f"{x:.{digits}g}" for x in a) + "]"


def _fmt_time_ms(t: float | None, sigma: float | None) -> str:
    """A clock offset in ms with as many decimals as its sigma needs (two significant digits
    of the sigma; microseconds without one), however large the offset (clocks of different
    epochs differ by years)."""
    if t is None:
        return "unobservable"
    s_ms = 1e-3 if sigma is None or not sigma > 0 else sigma * 1e3
    decimals = int(np.clip(1 - np.floor(np.log10(s_ms)), 0, 9))
    return f"{t * 1e3:.{decimals}f}"


def table(header: Sequence[str], rows: Sequence[Sequence[str]],
          right: Sequence[bool] | None = None) -> str:
    """The one text-table layout: columns padded to their widest cell, a rule under the header;
    ``right`` aligns numeric columns right."""
    right = right or [False] * len(header)
    w = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]

    def line(r: Sequence[str]) -> str:
        return "  ".join(f"{c:>{w[i]}}" if right[i] else f"{c:<{w[i]}}"
                         for i, c in enumerate(r)).rstrip()

    return "\n".join([line(header), "-" * (sum(w) + 2 * (len(w) - 1)), *map(line, rows)])


def _num(a: object) -> float | None:
    return None if a is None else float(np.asarray(a).ravel()[0])


def _time_row(label: str, t: float | None, sigma: float | None,
              fixed: bool) -> tuple[str, str, str, str]:
    """A clock offset in ms; ``fixed``: a value without a sigma was not estimated."""
    s_txt = ("fixed" if fixed and sigma is None and t is not None
             else _fmt(None if sigma is None else 1e3 * sigma, digits=2))
    return (label, _fmt_time_ms(t, sigma), s_txt, "ms")


def _parameter_rows(p: Parameter, value: Array | None, sigma: Array | None,
                    prefix: str = "", fixed: bool = True) -> list[tuple[str, str, str, str]]:
    """Table rows of one base parameter, as the registry says it prints."""
    pr = p.printed
    if p is TIME_OFFSET:
        return [_time_row(prefix + pr.label, _num(value), _num(sigma), fixed)]
    sig = _fmt(sigma, pr.sigma_scale, 2)
    if p.form == "so3":
        rv = None if value is None else so3.log(p.state(value))
        return [(f"{prefix}{pr.label} (rotation vector)", _fmt(rv, pr.value_scale), sig,
                 pr.unit),
                (f"{prefix}{pr.label} (quaternion wxyz)", _fmt(value, digits=6), "", "")]
    rows = [(prefix + pr.label, _fmt(value, pr.value_scale, pr.digits), sig, pr.unit)]
    if p.form == "s2" and value is not None:
        tilt = np.degrees(np.arccos(np.clip(-value[2], -1, 1)))
        rows.append(("mocap z tilt from vertical", f"{tilt:.4g}", "", "deg"))
    return rows


def summary_table(r: CalibrationResult) -> str:
    """Parameter | estimate | 1-sigma | unit, then the per-stage figures."""
    rows: list[tuple[str, str, str, str]] = []
    for t in r.takes:  # several takes: their own clock offsets and biases, not shared
        for p in PER_TAKE:
            rows += _parameter_rows(p, t.value(p), t.sigma(p), f"take {t.take} ", fixed=False)
    for p in PARAMETERS.values():
        if not (r.takes and p.per_take):
            rows += _parameter_rows(p, r.value(p), r.sigma(p))
    for name, rec in r.effects.items():
        for key, val in rec.items():
            if key != "sigma":
                rows += _value_rows(f"{name}.{key}", val, rec.get("sigma"))
    lines = [table(("parameter", "estimate", "1-sigma", "unit"), rows), ""]
    stage_rows = []
    for s in r.stages:
        unit = s.unit
        rms = s.rms_after
        if unit == "m":
            rms_txt = "[" + ", ".join(f"{x * 1e3:.3g}" for x in rms) + "] mm"
        elif unit == "deg":
            rms_txt = "[" + ", ".join(f"{x:.3g}" for x in rms) + "] deg"
        else:
            rms_txt = "[" + ", ".join(f"{x:.3g}" for x in rms) + f"] {unit}"
        stage_rows.append((s.name, str(s.n_factors), rms_txt, str(s.outliers), str(s.iterations),
                           f"{s.chi2_per_dof:.3f}", f"{s.seconds:.1f}s"))
    lines.append(table(("stage", "factors", "residual RMS per axis (after)", "outliers", "iter",
                        "chi2/dof", "time"), stage_rows,
                       (False, True, False, True, True, True, True)))
    lines += [""] + checks_lines(r)
    if r.unobservable:
        lines.append("")
        for k, why in r.unobservable.items():
            lines.append(f"UNOBSERVABLE {k}: {why}")
    lines += [x.line() for x in r.degraded]
    for n in r.notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)


def _value_rows(label: str, val: object, sig: object) -> list[tuple[str, str, str, str]]:
    """Table rows of one reported value: a matrix one row per line, a mapping (an effect's
    several parameters) one row per key, anything else one row."""
    if isinstance(val, dict):
        sig_d = sig if isinstance(sig, dict) else {}
        return [row for k, v in val.items() for row in _value_rows(f"{label}.{k}", v,
                                                                      sig_d.get(k))]
    if val is not None and np.asarray(val).ndim == 2:
        m = np.asarray(val)
        return [(label if i == 0 else "", _fmt(m[i]),
                 "" if sig is None else _fmt(np.asarray(sig)[i], digits=2), "")
                for i in range(m.shape[0])]
    return [(label, _fmt(val), _fmt(sig, digits=2), "")]


def checks_lines(r: CalibrationResult) -> list[str]:
    """One line each: the clock search, the plausibility verdict, the priors, the segments'
    consistency and the sensitivity to the noise densities."""
    out = []
    c = r.clock
    if c is not None:
        out.append(f"clock: coarse t_d {1e3 * c.time_offset:.3f} ms from "
                   f"{' + '.join(c.signals)} (peak {c.peak_z:.1f}, margin "
                   f"{c.margin_z:.1f} null sigmas"
                   + ("; chosen among equal peaks by the stage fits" if
                      c.verified_by_fit else "") + ")"
                   + (f", fine {1e3 * c.fine_time_offset:.3f} ms"
                      if c.fine_time_offset is not None else ""))
    pl = r.plausibility
    if pl is not None:
        fig = pl.figures
        where = (f" (up axis {fig.up_axis}, tilt {fig.tilt_deg:.2f} deg)"
                 if fig.up_axis is not None else "")
        out.append(f"plausibility: {pl.verdict}{where}"
                   + "".join(f"; FAILED: {x}" for x in pl.failed))
    out += priors_lines(r)
    cons = r.consistency
    if cons is not None and cons.max_pairwise_z:
        z = ", ".join(f"{p.symbol} {v:.2f}" for p, v in cons.max_pairwise_z.items())
        out.append(f"consistency ({len(cons.segments)} segments): largest pairwise "
                   f"|difference| / combined sigma: {z}")
    elif cons is not None and cons.note:
        out.append(f"consistency: {cons.note}")
    moved = (r.sensitivity.moved if r.sensitivity is not None else None) or {}
    if moved:
        parts = [f"{p.symbol} " + " / ".join(f"{moved[f].get(p, 0.0):.2f}" for f in moved)
                 for p in COMPARED if any(p in moved[f] for f in moved)]
        out.append(f"sensitivity (noise densities {' / '.join(moved)}): moves "
                   f"{', '.join(parts)} sigma")
    out += uncertainty_lines(r)
    return out


def priors_lines(r: CalibrationResult) -> list[str]:
    """The priors used and, per block, its largest |z| against the session's data alone."""
    pr = r.priors
    if pr is None:
        return []
    parts = [f"{b.label()} |z| {abs(b.z[b.worst]):.2g}" + (" CONFLICT" if b.conflict else "")
             if b.z else f"{b.label()} untested" for b in pr.blocks]
    return [f"priors ({', '.join(pr.sources)}) against the data alone: {', '.join(parts)}"
            + (f"; conflicting ones kept ({pr.conflicts[0].label()})" if pr.conflicts else "")]


#: The sigma rule's terms (docs/conventions.md, ``uncertainty:``; fields of
#: :class:`SigmaTerms`) and how they are shown.
UNCERTAINTY_TERMS = (("statistical", "statistical"), ("imu_noise_shift", "IMU noise"),
                     ("mocap_model_shift", "mocap model"),
                     ("effects_shown_shift", "effects shown"), ("largest_move", "largest move"),
                     ("total", "total"))


def uncertainty_lines(r: CalibrationResult) -> list[str]:
    """Per compared parameter (with several takes, per take for its own), the largest axis of
    each term of its sigma (which one dominates), in the unit its sigma prints in."""
    out = []
    for p in COMPARED:
        out += _terms_line(p, r.estimate(p).terms, "")
        for t in r.takes:
            e = t.estimates.get(p)
            out += _terms_line(p, None if e is None else e.terms, f" take {t.take}")
    return out


def _terms_line(p: Parameter, u: SigmaTerms | None, which: str) -> list[str]:
    if u is None:
        return []
    unit, k = p.printed.sigma_unit, p.printed.sigma_scale
    parts = [f"{label} {k * max(getattr(u, t)):.3g}" for t, label in UNCERTAINTY_TERMS
             if getattr(u, t) is not None]
    grown = (f" (statistical x{u.consistency_factor:.2f} for consistency)"
             if u.consistency_factor > 1.0 else "")
    return [f"sigma of {p.symbol}{which} ({unit}, largest axis): {', '.join(parts)}{grown}"]


def diagnose_table(report) -> str:
    """The diagnosis: per step the model, residual/floor ratios, the best candidates and what
    was added; then the verdict and the final calibration."""
    lines = [f"model diagnosis: start {report.start_model}", ""]
    for i, step in enumerate(report.steps):
        r = step.residuals
        final = i == len(report.steps) - 1
        title = "final" if final else f"step {i + 1}"
        lines.append(f"{title}: model {step.model}")
        g_axes = _fmt(r.gyro_rms / r.gyro_floor, digits=3)
        a_axes = _fmt(r.accel_rms / r.accel_floor, digits=3)
        lines.append(f"  low-band residual RMS / noise floor: gyro {r.ratio('gyro'):.3f} "
                     f"(per axis {g_axes}), accel {r.ratio('accel'):.3f} (per axis {a_axes})")
        if step.candidates:
            cand_rows = []
            for c in step.candidates[:4]:
                verdict = "ADDED" if c.effect == step.added else (
                    "significant" if c.significant else "refuted by its refit" if c.refuted
                    else "implausible" if c.implausible else "")
                refit = ("-" if np.isnan(c.confirm_log10_p) else f"{c.confirm_log10_p:.1f}")
                drop = "-" if np.isnan(c.residual_drop) else f"{100 * c.residual_drop:.1f}%"
                cand_rows.append((c.effect, f"{c.statistic:.1f}", str(c.dof), f"{c.log10_p:.1f}",
                                  refit, drop, verdict))
            tab = table(("candidate", "score T", "dof", "log10 p", "refit log10 p",
                         "resid. drop", "verdict"), cand_rows,
                        (False, True, True, True, True, True, False))
            lines += ["  " + x for x in tab.splitlines()]
            if len(step.candidates) > 4:
                lines.append(f"  ... {len(step.candidates) - 4} more, none better")
        if step.added is not None:
            lines.append(f"  -> added {step.added}: {_fmt(step.added_params, digits=3)}")
            lines.append(f"     1-sigma {_fmt(step.added_sigma, digits=2)}")
            best = next(c for c in step.candidates if c.effect == step.added)
            for t in best.takes or []:
                lines.append(f"     take {t['take']}: {_fmt(t['value'], digits=3)} "
                             f"(1-sigma {_fmt(t['sigma'], digits=2)}), log10 p "
                             f"{t['log10_p']:.1f}: "
                             + ("evidence there" if t["evidence"] else "no evidence alone"))
        lines.append("")
    lines.append(f"found: {', '.join(report.found) if report.found else 'none'}   "
                 f"(threshold log10 p < {report.threshold_log10_p:.2f})")
    for x in report.implausible:
        what = "tried again later" if x.get("takes_disagree") else "implausible"
        lines.append(f"{what} (step {x['step']}, not added): {x['reason']}")
    lines += unexplained_lines(report.unexplained)
    for n in report.notes:
        lines.append(f"note: {n}")
    lines.append("")
    lines.append(summary_table(report.final))
    return "\n".join(lines)


def unexplained_lines(u: dict | None) -> list[str]:
    """The signature of a residual no candidate explains, one line per finding."""
    if not u:
        return []
    out = ["UNEXPLAINED: no plausible candidate explains what is left: " + "; ".join(
        u.get("why") or ["the residual stays above the noise floor"])]
    for sensor in ("gyro", "accel"):
        sg = u.get(sensor) or {}
        axes = ", ".join(sg.get("axes_over_floor") or []) or "none"
        corr = sg.get("correlation") or {}
        best = max(corr.items(), key=lambda kv: abs(kv[1]["max_abs_corr"]), default=None)
        line = (f"  {sensor}: residual/floor per axis {_fmt(sg.get('ratio_per_axis'), digits=3)}"
                f" (axes over: {axes}), most in {sg.get('band_most_over_floor')}")
        if best is not None:
            name, c = best
            line += (f"; correlates with {name.replace('_', ' ')} ({c['max_abs_corr']:+.2f}, "
                     f"residual {c['residual_axis']} vs {c['signal_axis']})")
        out.append(line)
        out.append(f"  {sensor}: RMS per time segment (of the whole) "
                   f"{_fmt(sg.get('rms_per_time_segment'), digits=3)}")
    clock = u.get("clock_offset_per_segment") or {}
    if "t_d_ms" in clock:
        out.append(f"  clock offset per segment (ms): {_fmt(clock['t_d_ms'], digits=4)} (slope "
                   f"{_fmt(clock['slope_ppm'], digits=3)} ppm, largest jump "
                   f"{_fmt(clock['largest_jump_sigmas'], digits=3)} sigma)")
    elif clock.get("note"):
        out.append(f"  clock offset per segment: {clock['note']}")
    return out
