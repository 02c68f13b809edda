"""Sections of a calibration result about the session and the run: the clock search, the IMU's
gaps, each take's own answer, the solver's figures, the noise model identified from the data
and what ran degraded.

Each section is built once, by the pass that knows it, and never changed afterwards; it holds
the numbers the result file shows (rounded where the file rounds). ``to_dict``/``from_dict``
give the file's plain data (``docs/conventions.md``), called only by
:class:`~mocap_calib.core.result.calibration.CalibrationResult`'s own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mocap_calib.core.model.parameters import ACCEL_BIAS, GYRO_BIAS, TIME_OFFSET, Parameter
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.result.estimate import (
    Estimate,
    SigmaTerms,
    plain,
    read_sigma,
    read_value,
)

if TYPE_CHECKING:
    from mocap_calib.core.clock.search import ClockSearch
    from mocap_calib.core.prepare.gaps import ImuGaps


@dataclass(frozen=True)
class Degradation:
    """A step that could not run as intended and what the result lacks because of it.

    Attributes:
        what: the step (``consistency``, ``sensitivity``, ``position stage``, ...).
        why: what went wrong.
        consequence: what the result does without it.
    """

    what: str
    why: str
    consequence: str

    def line(self) -> str:
        """One line for the text summary."""
        return f"DEGRADED {self.what}: {self.why}; {self.consequence}"

    def to_dict(self) -> dict[str, str]:
        return {"what": self.what, "why": self.why, "consequence": self.consequence}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Degradation:
        return cls(str(d["what"]), str(d.get("why", "")), str(d.get("consequence", "")))


@dataclass(frozen=True)
class ClockSummary:
    """The coarse clock search (:class:`~mocap_calib.core.clock.search.ClockSearch` without its
    curve) and the fine offset of the position stage (None: not estimated, or several takes).
    Peaks are rounded as the file shows them."""

    time_offset: float
    signals: tuple[str, ...]
    peak_z: float
    margin_z: float
    second_offset: float | None
    restricted: bool
    verified_by_fit: bool
    candidates: tuple[tuple[float, float], ...] = ()
    fine_time_offset: float | None = None

    @classmethod
    def of(cls, c: ClockSearch, fine_time_offset: float | None = None) -> ClockSummary:
        return cls(c.time_offset, tuple(c.signals), round(c.peak_z, 2), round(c.margin_z, 2),
                   c.second_offset, c.restricted, c.verified_by_fit,
                   tuple((t, round(z, 2)) for t, z in c.candidates), fine_time_offset)

    def to_dict(self) -> dict[str, Any]:
        # The search's own file form (its module and scipy load only when a result is written).
        from mocap_calib.core.clock.search import ClockSearch

        d = ClockSearch(self.time_offset, self.signals, self.peak_z, self.margin_z,
                        self.second_offset, self.restricted, candidates=self.candidates,
                        verified_by_fit=self.verified_by_fit).to_dict()
        if self.fine_time_offset is not None:
            d["fine_time_offset"] = self.fine_time_offset
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ClockSummary | None:
        if not d:
            return None
        second, fine = d.get("second_best_time_offset"), d.get("fine_time_offset")
        return cls(float(d["coarse_time_offset"]), tuple(d.get("signals") or ()),
                   float(d["peak_z"]), float(d["margin_z"]),
                   None if second is None else float(second),
                   bool(d.get("searched_near_zero_first", False)),
                   bool(d.get("chosen_by_fit_among_peaks", False)),
                   # each candidate is a clock offset, under the parameter's name
                   tuple((float(c[TIME_OFFSET.name]), float(c["z"]))
                         for c in d.get("candidates") or ()),
                   None if fine is None else float(fine))


@dataclass(frozen=True)
class ImuGap:
    at_s: float
    length_s: float
    row: int


#: The counts of :class:`ImuGapsSummary`, in the file's order.
_GAP_COUNTS = ("count", "total_s", "longest_s", "bridged", "split", "segments",
               "trimmed_samples", "trimmed_s")


@dataclass(frozen=True)
class ImuGapsSummary:
    """What the IMU stream's gaps were and what was done (``docs/conventions.md``,
    ``imu_gaps:``): seconds on the IMU clock, rounded to 0.1 ms as the file shows them.
    ``gaps``: the first 50 (None in the sum over several takes, which has ``takes``)."""

    count: int
    total_s: float
    longest_s: float
    bridged: int
    split: int
    segments: int
    trimmed_samples: int
    trimmed_s: float
    gaps: tuple[ImuGap, ...] | None = ()
    takes: int | None = None

    @classmethod
    def of(cls, g: ImuGaps) -> ImuGapsSummary:
        lengths, split = g.lengths, g.split
        return cls(g.count, round(float(lengths.sum()), 4),
                   round(float(lengths.max()), 4) if g.count else 0.0,
                   int((~split).sum()), int(split.sum()), int(split.sum()) + 1, g.trimmed,
                   round(g.trimmed_s, 4),
                   tuple(ImuGap(round(float(b), 4), round(float(d), 4), int(r))
                         for b, d, r in zip(g.before, lengths, g.rows, strict=True))[:50])

    @classmethod
    def total(cls, parts: list[ImuGapsSummary]) -> ImuGapsSummary:
        """The takes' gaps together (each take's own list stays with the take)."""
        return cls(sum(p.count for p in parts), round(sum(p.total_s for p in parts), 4),
                   max(p.longest_s for p in parts), sum(p.bridged for p in parts),
                   sum(p.split for p in parts), sum(p.segments for p in parts),
                   sum(p.trimmed_samples for p in parts),
                   round(sum(p.trimmed_s for p in parts), 4), None, len(parts))

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {k: getattr(self, k) for k in _GAP_COUNTS}
        if self.gaps is not None:
            d["gaps"] = [{"at_s": g.at_s, "length_s": g.length_s, "row": g.row}
                         for g in self.gaps]
        if self.takes is not None:
            d["takes"] = self.takes
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> ImuGapsSummary | None:
        if not d:
            return None
        gaps = d.get("gaps")
        return cls(*(d[k] for k in _GAP_COUNTS),
                   None if gaps is None else tuple(
                       ImuGap(g["at_s"], g["length_s"], g["row"]) for g in gaps),
                   d.get("takes"))


#: A take's own parameters in the file's order.
TAKE_PARAMETERS: tuple[Parameter, ...] = (TIME_OFFSET, GYRO_BIAS, ACCEL_BIAS)


@dataclass(frozen=True)
class TakeResult:
    """One take of several calibrated together: its inputs as given, its own clock offset
    and biases (:data:`TAKE_PARAMETERS`, with the terms of their sigmas once judged), its
    session, gaps and clock search, counted from 1."""

    imu: str
    mocap: str
    estimates: Mapping[Parameter, Estimate]
    session: Mapping[str, Any]
    imu_gaps: ImuGapsSummary | None
    clock: ClockSummary | None
    take: int

    def value(self, p: Parameter) -> Any:
        e = self.estimates.get(p)
        return None if e is None else e.value

    def sigma(self, p: Parameter) -> Any:
        e = self.estimates.get(p)
        return None if e is None else e.sigma

    def to_dict(self) -> dict[str, Any]:
        ests = [(p, self.estimates.get(p, Estimate())) for p in TAKE_PARAMETERS]
        return {"imu": self.imu, "mocap": self.mocap,
                **{p.value_key[-1]: plain(p, e.value) for p, e in ests},
                "sigma": {p.sigma_key: plain(p, e.sigma) for p, e in ests},
                **({"uncertainty": {p.symbol: e.terms.to_dict() for p, e in ests
                                    if e.terms is not None}}
                   if any(e.terms is not None for _, e in ests) else {}),
                "session": self.session,
                **({"imu_gaps": self.imu_gaps.to_dict()} if self.imu_gaps else {}),
                **({"clock": self.clock.to_dict()} if self.clock else {}),
                "take": self.take}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TakeResult:
        sig = d.get("sigma") or {}
        unc = d.get("uncertainty") or {}
        return cls(str(d.get("imu", "")), str(d.get("mocap", "")),
                   {p: Estimate(read_value(p, d.get(p.value_key[-1]), p.value_key[-1]),
                                read_sigma(p, sig.get(p.sigma_key), f"sigma.{p.sigma_key}"),
                                SigmaTerms.from_dict(unc[p.symbol]) if p.symbol in unc
                                else None)
                    for p in TAKE_PARAMETERS},
                   dict(d.get("session") or {}), ImuGapsSummary.from_dict(d.get("imu_gaps")),
                   ClockSummary.from_dict(d.get("clock") or {}), int(d.get("take", 0)))


#: The keys of :class:`SolverFigures` that are its own fields (the rest are the stage's).
_SOLVER_OWN = ("total_seconds", "position_chi2_per_dof", "mocap_noise_per_axis",
               "step_seconds")


@dataclass(frozen=True)
class SolverFigures:
    """What the solve took and how it went.

    Attributes:
        total_seconds: the calibration's wall time (every step but start-up and reading).
        position_chi2_per_dof: the position stage's chi2/dof, rounded to 4 decimals.
        stage: the position stage's own figures, as it names them (windows, rounds, ...).
        mocap_noise_per_axis: ``(attitude_deg, position_mm)`` per axis at the solution.
        step_seconds: wall time of each step, in the order they ran.
    """

    total_seconds: float | None = None
    position_chi2_per_dof: float | None = None
    stage: Mapping[str, Any] = field(default_factory=dict)
    mocap_noise_per_axis: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    step_seconds: Mapping[str, float] | None = None

    @property
    def windows(self) -> int:
        return int(self.stage.get("windows", 0))

    @property
    def rounds(self) -> int:
        """The position stage's rounds (settling rounds and the final solve)."""
        return int(self.stage.get("position_rounds", 0))

    def with_steps(self, first: Mapping[str, float] | None = None,
                   last: Mapping[str, float] | None = None) -> SolverFigures:
        """These figures with steps added before (``first``) and after (``last``) those
        recorded (a step recorded again keeps its place and takes the new time)."""
        steps = {**(first or {}), **(self.step_seconds or {}), **(last or {})}
        return SolverFigures(self.total_seconds, self.position_chi2_per_dof, self.stage,
                             self.mocap_noise_per_axis, steps)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {}
        if self.total_seconds is not None:
            d["total_seconds"] = self.total_seconds
        if self.position_chi2_per_dof is not None:
            d["position_chi2_per_dof"] = self.position_chi2_per_dof
        d.update(self.stage)
        if self.mocap_noise_per_axis is not None:
            att, pos = self.mocap_noise_per_axis
            d["mocap_noise_per_axis"] = {"attitude_deg": list(att), "position_mm": list(pos)}
        if self.step_seconds is not None:
            d["step_seconds"] = dict(self.step_seconds)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> SolverFigures:
        d = d or {}
        per_axis = d.get("mocap_noise_per_axis")
        steps = d.get("step_seconds")
        return cls(d.get("total_seconds"), d.get("position_chi2_per_dof"),
                   {k: v for k, v in d.items() if k not in _SOLVER_OWN},
                   None if per_axis is None else (tuple(per_axis["attitude_deg"]),
                                                  tuple(per_axis["position_mm"])),
                   None if steps is None else dict(steps))


def per_axis_figures(att_deg: np.ndarray, pos_mm: np.ndarray
                     ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The mocap noise per axis as the solver figures keep it (4 decimals)."""
    return (tuple(round(float(x), 4) for x in att_deg),
            tuple(round(float(x), 4) for x in pos_mm))


@dataclass(frozen=True)
class NoiseIdentification:
    """The noise model the windows' likelihood prefers (:mod:`mocap_calib.core.position.noise`)
    and whether the calibration used it.

    Attributes:
        identified: the model the data prefer.
        given: the densities given (data sheet, ``--noise``, ``sensor.yaml``): the prior's
            centre.
        used: the data contradict the given densities (``gain`` over ``threshold``), so the
            identified model was used; otherwise the given one was.
        gain: ``-2 log L`` of the model the first solve used minus the identified one's, on
            the identification's windows.
        threshold: the chi-square quantile the gain is compared with.
        windows, samples: what the identification ran on.
    """

    identified: NoiseModel
    given: NoiseModel
    used: bool
    gain: float
    threshold: float
    windows: int
    samples: int

    def to_dict(self) -> dict[str, Any]:
        return {"used": self.used, "identified": self.identified.to_dict(),
                "given": self.given.to_dict(),
                "minus_2_log_likelihood_gain": round(self.gain, 1),
                "threshold": round(self.threshold, 2), "windows": self.windows,
                "samples": self.samples}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> NoiseIdentification | None:
        if not d:
            return None
        return cls(NoiseModel.from_dict(d.get("identified") or {}),
                   NoiseModel.from_dict(d.get("given") or {}), bool(d.get("used")),
                   float(d.get("minus_2_log_likelihood_gain", 0.0)),
                   float(d.get("threshold", 0.0)), int(d.get("windows", 0)),
                   int(d.get("samples", 0)))

    def summary(self) -> str:
        """One line for the notes: the levels found against those given, and what was done."""
        nz, g = self.identified, self.given
        axes = ""
        if not nz.isotropic:
            axes = (" (variance per IMU axis x" + ", ".join(
                f"{a:.2g}" for a in nz.accelerometer_axis_scale) + ")")
        corr = (f", {100 * nz.mocap_noise_corr_fraction:.0f} % of it correlated over "
                f"{nz.mocap_noise_corr_time:.2g} s" if nz.mocap_correlated else ", white")
        levels = (
            f"accelerometer {nz.accelerometer_noise_density:.3g} m/s^2/sqrt(Hz) "
            f"({nz.accelerometer_noise_density / g.accelerometer_noise_density:.3g} x the "
            f"{g.accelerometer_noise_density:.3g} given){axes}, gyro "
            f"{nz.gyroscope_noise_density:.3g} rad/s/sqrt(Hz) "
            f"({nz.gyroscope_noise_density / g.gyroscope_noise_density:.3g} x), mocap "
            f"{1e3 * nz.mocap_position_sigma:.3g} mm and "
            f"{np.degrees(nz.mocap_rotation_sigma):.3g} deg per sample{corr}")
        if self.used:
            return (f"noise identified from the data and used (the given densities are "
                    f"contradicted: -2 log L lower by {self.gain:.4g}): {levels}; "
                    "--fixed-noise holds the given ones")
        return (f"noise levels the data prefer ({levels}) do not contradict those given "
                f"(-2 log L lower by {self.gain:.3g}, below {self.threshold:.3g}): the given "
                "ones used")
