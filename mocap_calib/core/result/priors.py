"""Priors from earlier calibrations: one result gives its values and sigmas; two or more give a
first-order trend extrapolated to the new session (prior knowledge in factor-graph form).

Every block is handled in a local chart around the latest result (the rotation and gravity
tangent spaces of GTSAM's ``Rot3``/``Unit3``), a weighted straight line through the earlier
values is fitted per component (:func:`mocap_calib.core.model.trend.extrapolate_trend`), and the
line's value and uncertainty at the new session's time become the prior's mean and sigma.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.parameters import PARAMETERS, PER_TAKE
from mocap_calib.core.model.trend import extrapolate_trend
from mocap_calib.core.position.stage import Prior
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError

Array = NDArray[np.float64]


#: The rig's parameters first, then each session's own (the order of the priors).
RIG_FIRST = (*(p for p in PARAMETERS.values() if not p.per_take), *PER_TAKE)


def _blocks(r: CalibrationResult) -> dict[str, tuple[object, Array]]:
    """Value (natural form) and sigma (tangent) of every block the result determined."""
    out: dict[str, tuple[object, Array]] = {}
    for p in RIG_FIRST:
        v, sg = r.value(p), r.sigma(p)
        if v is None or sg is None or (p.scalar and not float(sg[0]) > 0):
            continue
        out[p.name] = (np.asarray(p.state(v), dtype=float), np.asarray(sg, dtype=float))
    for name, rec in r.effects.items():
        eff = EFFECTS.get(name)
        if eff is None or eff.acts_on in ("clock",) or rec.get("sigma") is None:
            continue
        value = rec.get(eff.param)
        if value is None:
            continue
        theta = eff.theta_from_report(value)
        sig = (np.einsum("kij,ij->k", eff.basis, np.asarray(rec["sigma"], dtype=float))
               if eff.acts_on in ("w", "f") else np.atleast_1d(np.asarray(rec["sigma"], float)))
        out[name] = (theta, sig)
    return out


def to_chart(name: str, value: object, ref: object) -> Array:
    """A block's value in the chart around ``ref`` (:meth:`Parameter.chart`; an effect's
    parameters are a plain vector)."""
    p = PARAMETERS.get(name)
    return np.asarray(value, dtype=float).ravel() if p is None else p.chart(ref, value)


def _from_chart(name: str, x: Array, ref: object) -> object:
    p = PARAMETERS.get(name)
    return x if p is None else p.from_chart(ref, x)


#: Blocks that change from one power-up or recording to the next: no prior by default.
SESSION_SPECIFIC = tuple(p.name for p in PER_TAKE)


def priors_from_results(results: Sequence[CalibrationResult], at_ns: int | None = None,
                        session_specific: bool = False) -> list[Prior]:
    """Priors for a new session from earlier results.

    Args:
        results: earlier calibrations (any order).
        at_ns: start of the new session (IMU clock, ns); needed with two or more results.
        session_specific: also give priors on the biases and the clock offset (turn-on biases
            and recorder clocks usually differ between sessions, so by default only the rig's
            geometry, the room's tilt and the IMU intrinsics carry over).

    Raises:
        InputError: two or more results without session times, or at the same time.
    """
    if not results:
        return []
    if len(results) == 1 or at_ns is None:
        if len(results) > 1 and at_ns is None:
            raise InputError("two or more --prior files need the new session's start time to "
                             "extrapolate their trend")
        r = results[0]
        return [Prior(n, v, s) for n, (v, s) in _blocks(r).items()
                if session_specific or n not in SESSION_SPECIFIC]
    times = []
    for r in results:
        t = r.session.get("imu_start_ns")
        if t is None:
            raise InputError("a --prior result has no session time (session.imu_start_ns); "
                             "use results written by this version of mocap-calib")
        times.append(int(t))
    order = np.argsort(times)
    results = [results[i] for i in order]
    t_s = (np.array(sorted(times), dtype=np.int64) - int(at_ns)) * 1e-9  # s, relative to now
    if np.ptp(t_s) <= 0:
        raise InputError("the --prior results are all from the same time; a trend needs "
                         "calibrations from different days")
    latest = _blocks(results[-1])
    priors: list[Prior] = []
    for name, (ref, _) in latest.items():
        if not session_specific and name in SESSION_SPECIFIC:
            continue
        xs, sig, ts = [], [], []
        for r, t in zip(results, t_s, strict=True):
            b = _blocks(r).get(name)
            if b is None:
                continue
            xs.append(to_chart(name, b[0], ref))
            sig.append(b[1])
            ts.append(t)
        if len(xs) < 2:
            continue
        # The line at t = 0 (now): times are relative to the new session.
        mean, sd = extrapolate_trend(np.asarray(ts), np.stack(xs), np.stack(sig), 0.0)
        priors.append(Prior(name, _from_chart(name, mean, ref), sd))
    return priors
