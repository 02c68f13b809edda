"""Priors on multi-position parameters from earlier results: one result as it is, several as
a first-order trend (:func:`mocap_calib.core.model.trend.extrapolate_trend`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.params import PARAMETERS
from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.intrinsics.multipos.units import RawConversion, change_units
from mocap_calib.core.model.trend import extrapolate_trend
from mocap_calib.errors import InputError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class MultiposPrior:
    """Gaussian prior on multi-position parameters, entered as weighted residual rows.

    Attributes:
        values: parameter name (a key of :data:`PARAMETERS`) -> value array of its shape.
        sigmas: same keys -> 1-sigma array of the same shape; entries that are not finite
            and positive (and the structural zeros above the diagonal of ``accel_matrix``)
            carry no prior.
        source: what the prior came from, for reports.
        counts: the values are for raw counts (``x = raw``), from raw-count calibrations;
            otherwise for SI readings.
    """

    values: Mapping[str, Array]
    sigmas: Mapping[str, Array]
    source: str = "prior"
    counts: bool = False

    def __post_init__(self) -> None:
        for name in self.values:
            if name not in PARAMETERS:
                raise InputError(f"prior: unknown parameter '{name}'; use "
                                 f"{', '.join(PARAMETERS)}")
            if name not in self.sigmas:
                raise InputError(f"prior: '{name}' has a value but no sigma; give both")
            shape = PARAMETERS[name]
            v = np.asarray(self.values[name], dtype=float)
            s = np.asarray(self.sigmas[name], dtype=float)
            if v.shape != shape or s.shape != shape:
                raise InputError(f"prior: '{name}' must have shape {shape}, got value "
                                 f"{v.shape} and sigma {s.shape}")

    def rows(self, name: str) -> tuple[Array, Array, NDArray[np.bool_]]:
        """(value, sigma, used) of one parameter, flattened; ``used`` false without a prior."""
        shape = PARAMETERS[name]
        if name not in self.values:
            z = np.zeros(int(np.prod(shape)))
            return z, z + np.inf, np.zeros(len(z), dtype=bool)
        v = np.asarray(self.values[name], dtype=float).ravel()
        s = np.asarray(self.sigmas[name], dtype=float).ravel()
        with np.errstate(invalid="ignore"):
            used = np.isfinite(v) & np.isfinite(s) & (s > 0)
        return v, s, used

    @classmethod
    def from_result(cls, result: MultiposResult | Mapping[str, Any],
                    names: Sequence[str] = tuple(PARAMETERS),
                    sigma_scale: float = 1.0) -> MultiposPrior:
        """Prior from one earlier calibration: its values and (scaled) sigmas.

        Args:
            result: a :class:`MultiposResult` or its ``to_dict()`` (e.g. read from YAML).
            names: which parameters to constrain (e.g. leave out the biases, which change
                from one power-up to the next more than their sigma says).
            sigma_scale: multiply the sigmas by this (> 1 to allow for change since then).
        """
        d = result.to_dict() if isinstance(result, MultiposResult) else result
        return cls.from_history([d], names=names, sigma_scale=sigma_scale)

    @classmethod
    def from_history(cls, results: Sequence[MultiposResult | Mapping[str, Any]],
                     times_s: Sequence[float] | None = None, at_time_s: float | None = None,
                     names: Sequence[str] = tuple(PARAMETERS),
                     sigma_scale: float = 1.0) -> MultiposPrior:
        """Prior from one or more earlier calibrations, extrapolating a first-order trend.

        With one result the prior is its values and sigmas. With two or more at distinct
        times, every entry gets a weighted straight-line fit against time, extrapolated to
        ``at_time_s``; its sigma is the prediction's standard error (scaled up by the fit's
        reduced chi-square when that exceeds 1), so the further the extrapolation, the wider.

        Args:
            results: earlier results (:class:`MultiposResult` or their ``to_dict()``).
            times_s: time of each result in s (any common origin); default: each result's
                ``diagnostics.session_time_ns``.
            at_time_s: time to extrapolate to (same origin); required with two or more.
            names: which parameters to constrain.
            sigma_scale: multiply the final sigmas by this.
        """
        dicts = [r.to_dict() if isinstance(r, MultiposResult) else r for r in results]
        if not dicts:
            raise InputError("prior: give at least one earlier result")
        for name in names:
            if name not in PARAMETERS:
                raise InputError(f"prior: unknown parameter '{name}'; use "
                                 f"{', '.join(PARAMETERS)}")
        if times_s is None and len(dicts) > 1:
            try:
                times_s = [float(d["diagnostics"]["session_time_ns"]) * 1e-9 for d in dicts]
            except (KeyError, TypeError):
                raise InputError("prior: earlier results have no session time; pass times_s "
                                 "with one time per result") from None
        values: dict[str, Array] = {}
        sigmas: dict[str, Array] = {}
        for name in names:
            y, s = _stack(dicts, name)
            if len(dicts) == 1:
                values[name], sigmas[name] = y[0], s[0] * sigma_scale
                continue
            if at_time_s is None:
                raise InputError("prior: with two or more earlier results give at_time_s, the "
                                 "time to extrapolate the trend to")
            v, sd = extrapolate_trend(np.asarray(times_s, dtype=float), y.reshape(len(y), -1),
                                      s.reshape(len(s), -1), float(at_time_s))
            shape = PARAMETERS[name]
            values[name], sigmas[name] = v.reshape(shape), sd.reshape(shape) * sigma_scale
        source = "earlier result" if len(dicts) == 1 else f"trend of {len(dicts)} results"
        return cls(values, sigmas, source)


def prior_in_units(prior: MultiposPrior, conv: RawConversion) -> MultiposPrior:
    """A raw-count prior (``counts``) for readings converted by ``conv``."""
    counts = RawConversion.identity("counts")
    values: dict[str, Array] = {}
    sigmas: dict[str, Array] = {}
    for name in prior.values:
        sensor = name.split("_")[0]
        v = np.asarray(prior.values[name], dtype=float)
        s = np.asarray(prior.sigmas[name], dtype=float)
        r = conv.scale(sensor)
        if name.endswith("matrix"):
            values[name], _ = change_units(v, np.zeros(3), counts, conv, sensor)
            sigmas[name] = s * r[:, None]
        else:
            _, values[name] = change_units(np.eye(3), v, counts, conv, sensor)
            sigmas[name] = s * r
    return MultiposPrior(values, sigmas, prior.source, counts=False)


def _stack(dicts: Sequence[Mapping[str, Any]], name: str) -> tuple[Array, Array]:
    """Values and sigmas of one parameter over the results, (n, *shape) each."""
    shape = PARAMETERS[name]
    try:
        y = np.array([np.asarray(d[name], dtype=float) for d in dicts])
        s = np.array([np.asarray(d["sigma"][name], dtype=float) for d in dicts])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"prior: an earlier result lacks '{name}' or its sigma "
                         f"('sigma: {{{name}: ...}}')") from None
    if y.shape[1:] != shape or s.shape[1:] != shape:
        raise InputError(f"prior: '{name}' must have shape {shape}")
    return y, s
