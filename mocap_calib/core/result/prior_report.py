"""The ``priors:`` section of a calibration result: every prior that entered the calibration,
against what the session's data say without it.

One row per prior block (and, for a take's own parameters with several takes, per take): the
result files it comes from (two or more: their trend), the prior's value and 1-sigma, the
data-alone value and 1-sigma (a refit without the priors), their difference in the tangent at
the data's value, the per-component z, and the block's chi-square statistic
``d^T (P_prior + P_data)^-1 d`` with the quantile it is compared with
(:mod:`mocap_calib.core.checks.priors`). ``to_dict``/``from_dict`` give the file's plain data
(``docs/conventions.md``), called only by
:class:`~mocap_calib.core.result.calibration.CalibrationResult`'s own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.parameters import PARAMETERS


def _floats(v: Any) -> tuple[float, ...]:
    return tuple(float(x) for x in np.atleast_1d(np.asarray(v, dtype=float)).ravel())


@dataclass(frozen=True)
class PriorBlock:
    """One prior block against the session's data.

    Attributes:
        block: the parameter's name (:data:`~mocap_calib.core.model.parameters.PARAMETERS`)
            or the effect's (:data:`~mocap_calib.core.model.effects.EFFECTS`).
        sources: the result files the prior comes from, as given.
        take: the take (counted from 1) of a take's own parameter with several takes; None
            otherwise.
        prior_value: the prior's value in the file's form (a rotation as quaternion wxyz,
            gravity as unit vector, an effect as its parameter vector).
        prior_sigma: its 1-sigma per tangent component.
        data_value: what the session's data alone say, in the same form (empty: not
            tested, the data-alone refit failed).
        data_sigma: their 1-sigma (statistical).
        difference: prior minus data, in the tangent at the data's value (SI, radians).
        z: per component, the difference over the combined sigma.
        statistic: ``d^T (P_prior + P_data)^-1 d`` (None: not tested).
        threshold: the chi-square quantile of the block's dimension it is compared with.
        conflict: the statistic exceeds the threshold.
    """

    block: str
    sources: tuple[str, ...]
    take: int | None
    prior_value: tuple[float, ...]
    prior_sigma: tuple[float, ...]
    data_value: tuple[float, ...] = ()
    data_sigma: tuple[float, ...] = ()
    difference: tuple[float, ...] = ()
    z: tuple[float, ...] = ()
    statistic: float | None = None
    threshold: float | None = None
    conflict: bool = False

    @property
    def symbol(self) -> str:
        """How notes name the block: a parameter's symbol, an effect's name."""
        p = PARAMETERS.get(self.block)
        return self.block if p is None else p.symbol

    @property
    def dof(self) -> int:
        return len(self.prior_sigma)

    @property
    def worst(self) -> int:
        """The component with the largest |z| (0 when not tested)."""
        return int(np.argmax(np.abs(self.z))) if self.z else 0

    def unit(self) -> tuple[str, float]:
        """The unit the block's differences and sigmas are shown in, and its factor from SI."""
        p = PARAMETERS.get(self.block)
        if p is not None:
            return p.printed.sigma_unit, p.printed.sigma_scale
        eff = EFFECTS.get(self.block)
        return ("" if eff is None else eff.unit), 1.0

    def component(self, k: int) -> str:
        """Component ``k``'s name: an axis, a gravity tilt, an effect's matrix entry."""
        p = PARAMETERS.get(self.block)
        if p is not None:
            if p.dim == 3:
                return f"{'xyz'[k]} axis"
            return f"tilt {k + 1}" if p.form == "s2" else p.symbol
        eff = EFFECTS.get(self.block)
        if eff is not None and eff.acts_on in ("w", "f"):
            i, j = np.argwhere(eff.basis[k] != 0)[0]
            return f"{eff.param}[{i},{j}]"
        return f"{self.block}[{k}]" if self.dof > 1 else self.block

    def size(self) -> str:
        """The difference's size in the block's unit (its norm), e.g. ``47 mm``."""
        unit, k = self.unit()
        return f"{k * float(np.linalg.norm(self.difference or 0.0)):.3g} {unit}".strip()

    def detail(self) -> str:
        """The component with the largest |z|: its z and both sigmas."""
        unit, k = self.unit()
        i = self.worst
        if not self.z:
            return "not tested"
        return (f"{self.component(i)}: z {self.z[i]:.3g} with the prior's "
                f"{k * self.prior_sigma[i]:.3g} {unit} and the data's "
                f"{k * self.data_sigma[i]:.3g} {unit} sigma").replace("  ", " ")

    def label(self) -> str:
        return self.symbol + ("" if self.take is None else f" (take {self.take})")

    def to_dict(self) -> dict[str, Any]:
        return {"parameter": self.block, "sources": list(self.sources),
                **({"take": self.take} if self.take is not None else {}),
                "prior": {"value": list(self.prior_value), "sigma": list(self.prior_sigma)},
                "data_alone": {"value": list(self.data_value), "sigma": list(self.data_sigma)},
                "difference": list(self.difference), "z": list(self.z),
                "statistic": self.statistic, "dof": self.dof, "threshold": self.threshold,
                "conflict": self.conflict}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> PriorBlock:
        prior, data = d.get("prior") or {}, d.get("data_alone") or {}
        take, stat, thr = d.get("take"), d.get("statistic"), d.get("threshold")
        return cls(str(d["parameter"]), tuple(str(s) for s in d.get("sources") or ()),
                   None if take is None else int(take), _floats(prior["value"]),
                   _floats(prior["sigma"]), _floats(data.get("value") or ()),
                   _floats(data.get("sigma") or ()), _floats(d.get("difference") or ()),
                   _floats(d.get("z") or ()), None if stat is None else float(stat),
                   None if thr is None else float(thr), bool(d.get("conflict", False)))


@dataclass(frozen=True)
class PriorsReport:
    """The priors used and how each agrees with the session's data.

    Attributes:
        tail_probability: a block conflicts when its statistic exceeds the chi-square quantile
            of this upper tail probability.
        blocks: one row per prior block (and take).
        kept_conflicting: conflicting priors were used anyway (``--trust-prior``).
        checked: the data-alone refit ran (false: it failed and the priors are used
            untested; the result's ``degraded:`` says why).
    """

    tail_probability: float
    blocks: tuple[PriorBlock, ...] = ()
    kept_conflicting: bool = False
    checked: bool = True

    @property
    def conflicts(self) -> tuple[PriorBlock, ...]:
        return tuple(b for b in self.blocks if b.conflict)

    @property
    def sources(self) -> tuple[str, ...]:
        """Every file a prior came from, in order, once each."""
        return tuple(dict.fromkeys(s for b in self.blocks for s in b.sources))

    def to_dict(self) -> dict[str, Any]:
        return {"tail_probability": self.tail_probability, "checked": self.checked,
                "kept_conflicting": self.kept_conflicting,
                "blocks": [b.to_dict() for b in self.blocks]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> PriorsReport | None:
        if not d:
            return None
        return cls(float(d["tail_probability"]),
                   tuple(PriorBlock.from_dict(b) for b in d.get("blocks") or ()),
                   bool(d.get("kept_conflicting", False)), bool(d.get("checked", True)))
