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
from mocap_calib.core.plausible import PlausibleLimits, effect_problem
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


def _numbers(value: object) -> Array | None:
    """``value`` as an array of floats (a mapping's values joined: the size effect's
    ``{r_y: [..], r_z: [..]}``), or None when it holds something else."""
    if isinstance(value, dict):
        parts = [_numbers(v) for v in value.values()]
        if any(p is None for p in parts) or not parts:
            return None
        return np.concatenate([p for p in parts if p is not None])
    try:
        return np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        return None


def _value_problem(key: str, value: object) -> str | None:
    a = _numbers(value)
    if a is None:
        return f"{key} is {value!r}, not numbers"
    if not np.all(np.isfinite(a)):
        return f"{key} is {a.tolist()}, not finite"
    return None


def _sigma_problem(key: str, sigma: object) -> str | None:
    """A sigma must be positive and finite, and its information (1/sigma^2) finite too."""
    a = _numbers(sigma)
    if a is None or not np.all(np.isfinite(a)):
        return f"{key} is {sigma!r}, not finite"
    with np.errstate(divide="ignore", over="ignore"):
        if not np.all((a > 0) & np.isfinite(1.0 / a**2)):
            return f"{key} is {a.tolist()}: a sigma must be positive"
    return None


def _result_values(r: CalibrationResult) -> list[tuple[str, object]]:
    """Every value of a result that a prior can take, by its key in the result file."""
    pairs: list[tuple[str, object]] = [
        ("T_marker_imu.rotation_wxyz", r.rotation_wxyz),
        ("T_marker_imu.translation", r.translation), ("gravity_in_mocap", r.gravity_in_mocap),
        ("gyro_bias", r.gyro_bias), ("accel_bias", r.accel_bias), ("time_offset", r.time_offset)]
    for name, rec in r.effects.items():
        eff = EFFECTS.get(name)
        if eff is not None and isinstance(rec, dict):
            pairs.append((f"effects.{name}.{eff.param}", rec.get(eff.param)))
    return [(k, v) for k, v in pairs if v is not None]


def _result_sigmas(r: CalibrationResult) -> list[tuple[str, object]]:
    pairs: list[tuple[str, object]] = [
        ("sigma.rotation", r.sigma_rotation), ("sigma.translation", r.sigma_translation),
        ("sigma.gravity_in_mocap", r.sigma_gravity), ("sigma.gyro_bias", r.sigma_gyro_bias),
        ("sigma.accel_bias", r.sigma_accel_bias)]
    if r.sigma_time_offset is not None and r.sigma_time_offset != 0:  # 0: no prior on it
        pairs.append(("sigma.time_offset", r.sigma_time_offset))
    for name, rec in r.effects.items():
        if isinstance(rec, dict) and rec.get("sigma") is not None:
            pairs.append((f"effects.{name}.sigma", _parameter_sigmas(name, rec["sigma"])))
    return [(k, v) for k, v in pairs if v is not None]


def _parameter_sigmas(name: str, sigma: object) -> object:
    """An effect's sigma as one number per parameter: a matrix term's sigmas are reported as
    a matrix whose entries outside the term (the upper triangle of a lower-triangular one)
    are zero, and only its own entries must be positive. Anything else as it is."""
    eff = EFFECTS.get(name)
    if eff is None or eff.acts_on not in ("w", "f"):
        return sigma
    try:
        m = np.asarray(sigma, dtype=float).reshape(3, 3)
    except (TypeError, ValueError):
        return sigma
    return np.einsum("kij,ij->k", eff.basis, m).tolist()


def prior_problems(r: CalibrationResult, limits: PlausibleLimits) -> list[str]:
    """Why an earlier result cannot be a prior, one line each naming its key: a value that is
    not finite, a rotation quaternion or gravity direction of no length, a lever arm or an
    effect beyond the plausibility ``limits`` (the gate the new result must pass too), a sigma
    that is not positive. Empty when it can be one. (Whether the prior agrees with the new
    session's data is the verdict's question, not this one.)"""
    problems = [p for k, v in _result_values(r) if (p := _value_problem(k, v))]
    problems += [p for k, s in _result_sigmas(r) if (p := _sigma_problem(k, s))]
    if problems:
        return problems
    for key, v in (("T_marker_imu.rotation_wxyz", r.rotation_wxyz),
                   ("gravity_in_mocap", r.gravity_in_mocap)):
        if v is not None and not np.any(np.asarray(v, dtype=float) != 0):
            problems.append(f"{key} is {np.asarray(v).tolist()}, of zero length: no direction")
    if r.translation is not None:
        arm = float(np.hypot.reduce(np.abs(np.asarray(r.translation, dtype=float))))
        if arm > limits.lever_arm:
            problems.append(f"T_marker_imu.translation puts the IMU {arm:.4g} m from the "
                            f"markers, beyond the plausible {limits.lever_arm:g} m "
                            "(--plausible lever_arm)")
    for name, rec in r.effects.items():
        eff = EFFECTS.get(name)
        if eff is not None and isinstance(rec, dict):
            problem = effect_problem(name, rec.get(eff.param), limits)
            if problem:
                problems.append(f"effects.{problem} (--plausible effects)")
    return problems


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
    t_s = (np.array(sorted(times), dtype=np.int64) - int(at_ns)) * 1e-9  # s, from this session
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
        # The line at t = 0: times are relative to the session being calibrated.
        mean, sd = extrapolate_trend(np.asarray(ts), np.stack(xs), np.stack(sig), 0.0)
        priors.append(Prior(name, _from_chart(name, mean, ref), sd))
    return priors
