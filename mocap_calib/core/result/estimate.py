"""One parameter's answer: its value, its 1-sigma and the terms the sigma is made of.

Values are in the result file's form (:class:`~mocap_calib.core.model.parameters.Parameter`:
a rotation as its quaternion wxyz, gravity as a unit vector, the clock offset as one number),
sigmas in the tangent convention of the parameter. The helpers at the bottom turn them into the
file's plain data and back (the file boundary, :meth:`CalibrationResult.to_dict`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.parameters import Parameter, by_symbol

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SigmaTerms:
    """The terms of a reported sigma (``docs/conventions.md``, ``uncertainty:``), per
    component: ``total = max(sqrt((factor * statistical)^2 + imu^2 + mocap^2 + effects^2),
    largest move)`` (:mod:`mocap_calib.core.checks.verdict`)."""

    statistical: Array
    consistency_factor: float
    imu_noise_shift: Array | None
    mocap_model_shift: Array | None
    effects_shown_shift: Array | None
    largest_move: Array | None
    total: Array

    def to_dict(self) -> dict[str, Any]:
        return {"statistical": _list(self.statistical),
                "consistency_factor": self.consistency_factor,
                "imu_noise_shift": _list(self.imu_noise_shift),
                "mocap_model_shift": _list(self.mocap_model_shift),
                "effects_shown_shift": _list(self.effects_shown_shift),
                "largest_move": _list(self.largest_move), "total": _list(self.total)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SigmaTerms:
        return cls(_req(d, "statistical"), float(d.get("consistency_factor", 1.0)),
                   _opt(d.get("imu_noise_shift")), _opt(d.get("mocap_model_shift")),
                   _opt(d.get("effects_shown_shift")), _opt(d.get("largest_move")),
                   _req(d, "total"))


@dataclass(frozen=True)
class Estimate:
    """A parameter's value (file form; None: not determined, or not shared by the takes), its
    1-sigma (tangent; None: not estimated) and, once judged, the terms of that sigma."""

    value: Array | None = None
    sigma: Array | None = None
    terms: SigmaTerms | None = None

    @classmethod
    def of(cls, p: Parameter, value: Any, sigma: Any) -> Estimate:
        """From numbers (a scalar parameter may be given as a float)."""
        return cls(_vec(value, p.value_dim, p.name), _vec(sigma, p.dim, f"sigma.{p.name}"))


def _list(a: Array | None) -> list[float] | None:
    return None if a is None else [float(x) for x in np.asarray(a).ravel()]


def _opt(x: Any) -> Array | None:
    return None if x is None else np.asarray(x, dtype=float)


def _req(d: Mapping[str, Any], key: str) -> Array:
    return np.atleast_1d(np.asarray(d[key], dtype=float))


def _vec(x: Any, n: int, name: str) -> Array | None:
    """A float vector of ``n`` numbers (or None); ValueError names the key otherwise."""
    if x is None:
        return None
    a = np.atleast_1d(np.asarray(x, dtype=float))
    if a.shape != (n,):
        raise ValueError(f"'{name}' must be {'a number' if n == 1 else f'a list of {n} numbers'}"
                         f", got {x!r}")
    return a


def plain(p: Parameter, a: Array | None) -> float | list[float] | None:
    """A value or sigma as the file writes it: a bare number for a scalar parameter."""
    if a is None:
        return None
    return float(np.asarray(a).ravel()[0]) if p.scalar else _list(a)


def read_value(p: Parameter, x: Any, key: str) -> Array | None:
    return _vec(x, p.value_dim, key)


def read_sigma(p: Parameter, x: Any, key: str) -> Array | None:
    return _vec(x, p.dim, key)


def by_symbol_map(d: Mapping[str, Any] | None) -> dict[Parameter, Any]:
    """A section keyed by parameter symbols (``R_MI: ...``) keyed by the parameters."""
    return {by_symbol(k): v for k, v in (d or {}).items()}


def symbol_map(d: Mapping[Parameter, Any]) -> dict[str, Any]:
    """Inverse of :func:`by_symbol_map`."""
    return {p.symbol: v for p, v in d.items()}
