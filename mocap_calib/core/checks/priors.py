"""Priors against the session's data: does each prior from an earlier calibration agree with
what this session's data say without it?

After the fit (with the priors) the data alone are refitted from the solution without them:
up to :data:`DATA_ALONE_STEPS` Gauss-Newton steps
(:func:`~mocap_calib.core.uncertainty.refit.refit`; between steps the mocap levels and robust
weights follow the innovations, as a full run's rounds would). Per prior block, the difference
``d`` = prior minus data (in the tangent at the data's value: a rotation by SO(3)'s log, the
gravity direction in GTSAM's ``Unit3`` tangent) is tested by ``d^T (P_prior + P_data)^-1 d``
against the chi-square quantile of the block's dimension at :data:`TAIL_PROBABILITY`.

A conflict refuses the run (:class:`~mocap_calib.errors.InputError`, exit 2: the prior is bad
input for this session) with one line naming the prior's file, the parameter, the size of the
disagreement and its largest z; with ``trust_prior`` the prior is used and the result's note
and ``priors:`` section name the conflict. Either way the result says which priors were used
(:class:`~mocap_calib.core.result.prior_report.PriorsReport`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    PARAMETERS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
)
from mocap_calib.core.model.stats import chi2_isf
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.position.engine import Theta
from mocap_calib.core.position.graph import Prior
from mocap_calib.core.position.stage import PositionResult, block_value
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.prior_report import PriorBlock, PriorsReport
from mocap_calib.core.result.sections import Degradation
from mocap_calib.core.uncertainty.refit import everything, refit, sigmas, z_pair
from mocap_calib.errors import CalibrationError, InputError, Interrupted

Array = NDArray[np.float64]

#: A prior block conflicts with the data when its statistic exceeds the chi-square quantile
#: of this upper tail probability (about 1 in 1000 consistent blocks refused by chance).
TAIL_PROBABILITY = 1e-3
#: Most Gauss-Newton steps of the data-alone refit (it stops once a step moves no compared
#: parameter by :data:`SETTLED_SIGMA` of its sigma).
DATA_ALONE_STEPS = 8
SETTLED_SIGMA = 0.1
#: The option that uses a conflicting prior anyway, as the refusal names it.
TRUST_OPTION = "--trust-prior"


def check_priors(r: CalibrationResult, pos: PositionResult, opts: CalibrationOptions,
                 say: Callable[[str], None]) -> CalibrationResult:
    """``r`` with its ``priors`` section and note (unchanged without priors).

    Raises:
        InputError: a prior conflicts with the session's data and
            ``opts.trust_prior`` is off.
    """
    used = [p for p in opts.priors if _data_alone_of(p, pos, opts.model) is not None]
    if not used:
        return r
    say("priors: the session's data refitted without them, each prior tested against them")
    try:
        alone = _refit_alone(pos, opts)
    except Interrupted:
        raise
    except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
        report = PriorsReport(TAIL_PROBABILITY, tuple(_untested(p) for p in used),
                              opts.trust_prior, checked=False)
        return replace(r, priors=report).with_notes(used_line(report)).with_degraded(
            Degradation("prior check", f"the refit without the priors failed ({err})",
                        "the priors are used untested against the session's data"))
    blocks = []
    for p in used:
        threshold = chi2_isf(TAIL_PROBABILITY, len(np.atleast_1d(p.sigma)))
        for take, state, cov in _data_alone_of(p, alone, opts.model) or []:
            blocks.append(_tested(p, take, state, cov, threshold))
    report = PriorsReport(TAIL_PROBABILITY, tuple(blocks), opts.trust_prior)
    if report.conflicts and not opts.trust_prior:
        raise InputError(refusal_line(_worst(report.conflicts)))
    return replace(r, priors=report).with_notes(used_line(report))


def _refit_alone(pos: PositionResult, opts: CalibrationOptions) -> PositionResult:
    """The solution refitted without the user's priors (the weak range priors stay)."""
    sig = sigmas(pos)

    def settled(a: Theta, b: Theta) -> bool:
        return max(z_pair(a, b, sig, None).values()) < SETTLED_SIGMA

    adapt = pos.identification is None or not pos.identification.contradicts
    return refit(pos, opts.model, everything(pos), adapt_noise=adapt, reweight=True,
                 priors=None, max_iterations=opts.max_iterations, one_step=DATA_ALONE_STEPS,
                 settled=settled, time_mean=True)


def _data_alone_of(prior: Prior, fit: PositionResult, model: Model
                   ) -> list[tuple[int | None, Array, Array]] | None:
    """What ``fit`` says of the prior's block: per take for a take's own parameter (take
    counted from 1, None with one take), its value (the graph's form) and covariance; None
    when the model has no such block (the prior did not enter the graph)."""
    name = prior.block
    p = PARAMETERS.get(name)
    several = len(fit.takes) > 1
    if p is not None and p.per_take:
        out = []
        for k, t in enumerate(fit.takes):
            if name not in t.cov:
                return None
            own = {TIME_OFFSET: np.array([t.delta - t.s.clock_shift]),
                   GYRO_BIAS: t.gyro_bias_mean, ACCEL_BIAS: t.accel_bias_mean}
            out.append((k + 1 if several else None, own[p], t.cov[name]))
        return out
    if name not in fit.cov:
        return None
    if p is not None:
        shared = {ROTATION: fit.R_MI, TRANSLATION: fit.p_MI, GRAVITY_DIRECTION: fit.g_dir}
        return [(None, shared[p], fit.cov[name])]
    if name not in EFFECTS or not model.has(name):
        return None
    return [(None, block_value(fit, name, fit.takes[0].s.clock_shift), fit.cov[name])]


def _forms(prior: Prior, data_state: Array) -> tuple[Array, Array, Array]:
    """The prior's and the data's values in the file's form, and prior minus data in the
    tangent at the data's value."""
    p = PARAMETERS.get(prior.block)
    if p is None:
        pv = np.atleast_1d(np.asarray(prior.value, dtype=float)).ravel()
        dv = np.atleast_1d(np.asarray(data_state, dtype=float)).ravel()
        return pv, dv, pv - dv
    prior_state = np.asarray(prior.value, dtype=float)
    if p.scalar:
        prior_state = np.atleast_1d(prior_state).ravel()
    return (p.value_of(prior_state), p.value_of(data_state),
            p.difference(data_state, prior_state))


def _tested(prior: Prior, take: int | None, data_state: Array, cov: Array,
            threshold: float) -> PriorBlock:
    """One block's test: ``d^T (P_prior + P_data)^-1 d`` against ``threshold``."""
    pv, dv, d = _forms(prior, data_state)
    s_prior = np.atleast_1d(np.asarray(prior.sigma, dtype=float)).ravel()
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    P = 0.5 * (cov + cov.T) + np.diag(s_prior**2)
    stat = float(d @ np.linalg.solve(P, d))
    z = d / np.sqrt(np.diag(P))
    s_data = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return PriorBlock(prior.block, prior.sources, take, _t(pv), _t(s_prior), _t(dv), _t(s_data),
                      _t(d), tuple(round(float(x), 3) for x in z), round(stat, 3),
                      round(threshold, 3), stat > threshold)


def _untested(prior: Prior) -> PriorBlock:
    pv, _, _ = _forms(prior, np.asarray(prior.value, dtype=float))
    return PriorBlock(prior.block, prior.sources, None, _t(pv),
                      _t(np.atleast_1d(np.asarray(prior.sigma, dtype=float))))


def _t(a: Array) -> tuple[float, ...]:
    return tuple(float(x) for x in np.atleast_1d(np.asarray(a, dtype=float)).ravel())


def _worst(blocks: tuple[PriorBlock, ...]) -> PriorBlock:
    """The block that disagrees most: the largest statistic beyond its threshold."""
    return max(blocks, key=lambda b: (b.statistic or 0.0) / (b.threshold or 1.0))


def _given(b: PriorBlock) -> str:
    """Where the prior came from, as the refusal starts."""
    if not b.sources:
        return "a prior"
    if len(b.sources) == 1:
        return f"{b.sources[0]}: as a --prior"
    return f"{', '.join(b.sources)}: as --prior (their trend)"


def _why(block: str) -> str:
    """What a disagreement of this block usually means."""
    p = PARAMETERS.get(block)
    if p is not None and p.per_take:
        return "it changes between power-ups and recordings"
    if p is not None and p.form == "s2":
        return "the mocap system's world was set up again or the prior is another room's"
    if p is not None:
        return "the IMU was remounted or the prior is another rig's"
    eff = EFFECTS.get(block)
    if eff is not None and eff.sensor == "world":
        return "the prior is from another site or setup"
    return "the IMU's intrinsics changed or the prior is another IMU's"


def refusal_line(b: PriorBlock) -> str:
    """The one line a conflicting prior is refused with."""
    return (f"{_given(b)}, {b.label()} is {b.size()} from what this session's data say "
            f"({b.detail()}): {_why(b.block)}; drop it, or pass {TRUST_OPTION} to use it "
            "anyway")


def used_line(report: PriorsReport) -> str:
    """The result's note: which priors were used, from which files, and how they agree with
    the session's data."""
    names = ", ".join(dict.fromkeys(b.label() for b in report.blocks))
    head = (f"priors used from {', '.join(report.sources)} ({names})" if report.sources
            else f"priors used ({names})")
    if not report.checked:
        return f"{head}, untested against this session's data (the refit without them failed)"
    if report.conflicts:
        return f"{head}; CONFLICTING, kept with {TRUST_OPTION}: " + "; ".join(
            f"{b.label()} is {b.size()} from what this session's data say ({b.detail()})"
            for b in report.conflicts) + "; the answer leans on the prior"
    b = max(report.blocks, key=lambda x: max(np.abs(x.z), default=0.0))
    return (f"{head}: each agrees with what this session's data say alone (largest |z| "
            f"{abs(b.z[b.worst]):.2g}, {b.label()} {b.component(b.worst)}; chi-square at tail "
            f"probability {report.tail_probability:g})")
