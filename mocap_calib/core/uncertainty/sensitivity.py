"""Does the answer depend on a noise model the session cannot check?

- IMU noise densities: the white noise and random walks scaled by 3 and by 1/3 reweight the
  data; an answer that moves by more than its sigma depends on an assumption the session
  cannot check.
- The mocap noise's correlation: the point estimate takes it white (with its level from the
  residuals). Real mocap noise is band-limited (vibration, marker-body flex, the pose solver's
  filters), and neither white nor AR(1) is right; so the AR(1) model that the windows' exact
  likelihood prefers is fitted once, at the solution and at the engine's rate, and the answer
  refitted under it. How far it moves is model uncertainty, carried into the sigmas like the
  IMU densities' (:mod:`mocap_calib.core.checks.verdict`).
- The effects the data show (the score tests at the solution) but the model lacks: the answer
  refitted with them added. The data say the model is incomplete; how far completing it moves
  the answer is model uncertainty too (``--model auto`` fits them instead).

Each refit starts at the solution and takes up to :data:`REFIT_STEPS` Gauss-Newton steps (it
stops once a step moves nothing by a tenth of a sigma), between which the mocap levels and the
robust weights follow the innovations, as a full run's rounds would.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
    Parameter,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.plausible import PlausibleLimits, effect_problem
from mocap_calib.core.position.engine import PositionProblem, Theta
from mocap_calib.core.position.graph import Prior
from mocap_calib.core.position.stage import PositionResult, effect_estimate
from mocap_calib.core.uncertainty.mocap_noise import fit_mocap_correlation
from mocap_calib.core.uncertainty.refit import everything, refit, sigmas, z_pair
from mocap_calib.errors import CalibrationError, Interrupted

Array = NDArray[np.float64]

#: A refit stops stepping once a step moves no parameter by this many sigmas.
SETTLED_SIGMA = 0.1
#: Most Gauss-Newton steps of a refit. Under the IMU densities x1/3 the lever arm walks a
#: long way on EuRoC V2_03: after 3 steps the refit said 0.7 sigma where a rerun from
#: scratch moved 1.6; after 8 it covers the rerun (0.99).
REFIT_STEPS = 8
#: The correlated model's fit uses at most this many windows (spread over the session).
CORRELATION_WINDOWS = 60
#: Its candidates (time constant s, correlated fraction); (0, 0) is white noise.
CORRELATION_GRID: tuple[tuple[float, float], ...] = (
    (0.0, 0.0), *((T, rho) for T in (0.1, 0.3, 1.0, 3.0) for rho in (0.5, 0.9)))
#: A shift counts as systematic only when its square exceeds this many times the variance the
#: reweighting explains by chance (a 2-sigma difference, the 5 % level): the positive part of
#: every chance difference would pad a correct model's sigmas (on simulations with the noise
#: model right, by ~0.4 of the chance variance per component and alternative).
SIGNIFICANT = 4.0
#: The key of the correlated mocap model among the alternatives.
MOCAP_AR1 = "mocap_ar1"
#: The key of the model with the effects the data show (the effect tests) among them.
EFFECTS_SHOWN = "effects_shown"

@dataclass
class Sensitivity:
    """How far the answer moves under other noise models.

    Attributes:
        shift: alternative -> parameter -> |change| per component beyond what the reweighting
            explains by chance (parameter units; rotation and gravity in rad); zero where the
            change is within chance (:data:`SIGNIFICANT`).
        raw: alternative -> parameter -> |change|.
        moved: alternative -> compared parameter -> largest |change| / the statistical sigma.
        mocap_model: the correlated mocap model fitted (time constant, fraction, likelihood
            gain over white noise) when one was.
        implausible: why the model with the effects the data show was left out (its fit
            gives an effect no physical IMU has: not a credible completion of the model).
        failed: alternative -> why its refit failed (the alternative is then left out).
    """

    shift: dict[str, dict[Parameter, Array]] = field(default_factory=dict)
    raw: dict[str, dict[Parameter, Array]] = field(default_factory=dict)
    moved: dict[str, dict[Parameter, float]] = field(default_factory=dict)
    mocap_model: dict[str, float] = field(default_factory=dict)
    implausible: str = ""
    #: With several takes, per alternative and take, the shifts of the take's own parameters.
    take_shift: dict[str, list[dict[Parameter, Array]]] = field(default_factory=dict)
    take_raw: dict[str, list[dict[Parameter, Array]]] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)

    @property
    def note(self) -> str:
        """The last failed alternative, as the result file's ``note`` names it."""
        if not self.failed:
            return ""
        key, why = list(self.failed.items())[-1]
        return f"{key}: refit failed ({why})"

    def systematic(self, p: Parameter, which: tuple[str, ...] | None = None) -> Array | None:
        """Per component, the largest shift beyond chance over the alternatives (``which``:
        only those), or None when not computed."""
        shifts = [d[p] for k, d in self.shift.items()
                  if p in d and (which is None or k in which)]
        return np.max(np.stack(shifts), axis=0) if shifts else None

    def largest_move(self, p: Parameter) -> Array | None:
        """Per component, the largest plain |change| over the alternatives, of the changes
        beyond chance (a chance difference is no answer a user of that model would get more
        than this one)."""
        moves = [np.where(self.shift[k][p] > 0.0, d[p], 0.0) for k, d in self.raw.items()
                 if p in d and p in self.shift.get(k, {})]
        return np.max(np.stack(moves), axis=0) if moves else None

    def of_take(self, k: int) -> Sensitivity:
        """The same for take ``k``'s own parameters (clock offset, biases): each alternative's
        shift of that take's values, so that they carry the terms a single run's do."""
        return Sensitivity({a: d[k] for a, d in self.take_shift.items() if k < len(d)},
                           {a: d[k] for a, d in self.take_raw.items() if k < len(d)})


def gyro_frame(pos: PositionResult) -> Array:
    """R_GI: the gyro's axes against the IMU (accelerometer) frame that the model's gyro matrix
    implies (the rotation of its polar decomposition; identity without one). A model without
    that matrix reports R_MI close to the gyro's frame, which dominates the attitude; so a model
    with it is compared in that frame (``R_MI R_GI^T``), not across two frame definitions."""
    R = np.eye(3)
    for name, theta in pos.effects.items():
        eff = EFFECTS[name]
        if eff.acts_on == "w" and eff.about_identity:
            U, _, Vt = np.linalg.svd(np.eye(3) + eff.matrix(theta))
            R = (U @ Vt) @ R
    return R


def _shifts(alt: PositionResult, pos: PositionResult
            ) -> tuple[dict[Parameter, Array], dict[Parameter, Array]]:
    """Per parameter and component, the part of |alt - pos| that the reweighting itself does
    not explain, and the plain |alt - pos|. Two estimates from the same data under different
    weights differ by chance with variance about |var_alt - var| (Hausman; of the biases, the
    knots' means' own variances); only the excess is a systematic shift."""
    R_alt = alt.R_MI @ gyro_frame(alt).T @ gyro_frame(pos)
    raw = {ROTATION: ROTATION.difference(pos.R_MI, R_alt),
           TRANSLATION: TRANSLATION.difference(pos.p_MI, alt.p_MI),
           GYRO_BIAS: GYRO_BIAS.difference(pos.gyro_bias_mean, alt.gyro_bias_mean),
           ACCEL_BIAS: ACCEL_BIAS.difference(pos.accel_bias_mean, alt.accel_bias_mean),
           GRAVITY_DIRECTION: GRAVITY_DIRECTION.difference(pos.g_dir, alt.g_dir)}
    if TIME_OFFSET.name in pos.cov:
        raw[TIME_OFFSET] = TIME_OFFSET.difference(pos.delta, alt.delta)
    return _beyond_chance(raw, {**alt.cov, **alt.takes[0].cov_knots},
                          {**pos.cov, **pos.takes[0].cov_knots})


def _beyond_chance(raw: dict[Parameter, Array], cov_alt: dict[str, Array],
                   cov: dict[str, Array]) -> tuple[dict[Parameter, Array], dict[Parameter, Array]]:
    """The part of each difference that the reweighting does not explain by chance (zero
    unless the difference is significant, :data:`SIGNIFICANT`), and the plain |difference|."""
    excess = {}
    for p, d in raw.items():
        chance = 0.0
        if p.name in cov and p.name in cov_alt:
            chance = np.abs(np.diag(cov_alt[p.name]) - np.diag(cov[p.name]))
        excess[p] = np.where(d**2 > SIGNIFICANT * chance,
                             np.sqrt(np.maximum(d**2 - chance, 0.0)), 0.0)
    return excess, {k: np.abs(v) for k, v in raw.items()}


def _take_shifts(alt: PositionResult, pos: PositionResult
                 ) -> tuple[list[dict[Parameter, Array]], list[dict[Parameter, Array]]]:
    """Per take, :func:`_shifts` of its own clock offset and biases."""
    shift, raw = [], []
    for a, b in zip(alt.takes, pos.takes, strict=True):
        d = {GYRO_BIAS: GYRO_BIAS.difference(b.gyro_bias_mean, a.gyro_bias_mean),
             ACCEL_BIAS: ACCEL_BIAS.difference(b.accel_bias_mean, a.accel_bias_mean)}
        if TIME_OFFSET.name in b.cov:
            d[TIME_OFFSET] = TIME_OFFSET.difference(b.delta, a.delta)
        s, r = _beyond_chance(d, {**a.cov, **a.cov_knots}, {**b.cov, **b.cov_knots})
        shift.append(s)
        raw.append(r)
    return shift, raw


def noise_sensitivity(pos: PositionResult, model: Model,
                      factors: tuple[float, ...] = (3.0, 1.0 / 3.0),
                      max_iterations: int = 30, one_step: bool | int = REFIT_STEPS,
                      priors: list[Prior] | None = None,
                      mocap_model: bool = True,
                      effects_shown: tuple[str, ...] = (),
                      limits: PlausibleLimits | None = None) -> Sensitivity:
    """Refit with the IMU noise densities scaled, and under the correlated mocap noise model
    the session prefers (``mocap_model``), and with the effects the data show
    (``effects_shown``) added to ``model``, as full runs given those models would land.

    User priors come from earlier sessions calibrated under the same densities, so their
    sigmas scale with them: the balance between prior and data stays, and a prior that
    disagrees with a short session by chance does not pass for a systematic."""
    out = Sensitivity()
    sig = sigmas(pos)

    def settled(a: Theta, b: Theta) -> bool:
        # A step below a tenth of a sigma: the rest of the way is smaller still.
        return max(z_pair(a, b, sig, None).values()) < SETTLED_SIGMA

    # Mocap levels identified from the likelihood stay; levels from the residuals follow
    # them again, as a run given the other model would.
    adapt = pos.identification is None or not pos.identification.contradicts

    def run(key: str, noise: NoiseModel, scale: float,
            alt_model: Model = model) -> PositionResult | None:
        scaled_priors = [replace(p, sigma=np.asarray(p.sigma) * scale) for p in priors or []]
        interrupt.check()
        try:
            alt = refit(pos, alt_model, everything(pos), noise=noise, adapt_noise=adapt,
                        reweight=True, priors=scaled_priors, max_iterations=max_iterations,
                        one_step=one_step, settled=settled)
        except Interrupted:
            raise
        except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
            out.failed[key] = str(err)
            return None
        if key == EFFECTS_SHOWN:
            why = _implausible_effect(alt, alt_model, model, limits)
            if why:
                out.implausible = why
                return None
        out.shift[key], out.raw[key] = _shifts(alt, pos)
        if len(pos.takes) > 1:
            out.take_shift[key], out.take_raw[key] = _take_shifts(alt, pos)
        out.moved[key] = z_pair(alt, pos, sig, None)
        return alt

    for f in factors:
        run(f"x{f:.3g}", pos.noise.imu_scaled(f), f)
    if mocap_model and not pos.noise.mocap_correlated:
        corr = correlated_mocap_model(pos, model)
        if corr is not None:
            noise, out.mocap_model = corr
            run(MOCAP_AR1, noise, 1.0)
    if effects_shown:
        fuller = model
        for name in effects_shown:
            fuller = fuller.with_effect(name)
        run(EFFECTS_SHOWN, pos.noise, 1.0, fuller)
    return out


def _implausible_effect(alt: PositionResult, fuller: Model, model: Model,
                        limits: PlausibleLimits | None) -> str:
    """Why an effect fitted in the fuller model is not physical (empty: all plausible)."""
    for name in fuller.effects:
        if model.has(name) or EFFECTS[name].acts_on == "clock":
            continue
        value, _ = effect_estimate(alt, name, 0.0)
        problem = effect_problem(name, value, limits or PlausibleLimits())
        if problem:
            return problem
    return ""


def _theta(pos: PositionResult, t: Any) -> Theta:
    """The parameters of the solution with take ``t``'s clock and biases."""
    return Theta(pos.R_MI, pos.p_MI, pos.g_dir, gtsam.Unit3(pos.g_dir).basis(), pos.g_mag,
                 t.delta, dict(pos.effects), t.knots, t.take.t_mid)


def correlated_mocap_model(pos: PositionResult,
                           model: Model) -> tuple[NoiseModel, dict[str, float]] | None:
    """The AR(1) mocap noise model the windows' exact likelihood prefers, fitted at the
    solution on up to :data:`CORRELATION_WINDOWS` windows of the take with the most, at the
    engine's rate; None when white noise fits best. Fitted once per solution (the effect
    tests and the sensitivity share it)."""
    return pos.memo.get("correlated_mocap_model", lambda: _fit_correlated(pos, model))


def _fit_correlated(pos: PositionResult,
                    model: Model) -> tuple[NoiseModel, dict[str, float]] | None:
    k = max(range(len(pos.takes)), key=lambda i: pos.takes[i].windows.count)
    t = pos.takes[k]
    problem = PositionProblem(t.s, model, pos.noise, t.windows, split=False)
    problem.weights = t.weights
    problem.mocap_axis_scale = pos.axis_scale.copy()
    fit = fit_mocap_correlation(problem, _theta(pos, t), CORRELATION_GRID, CORRELATION_WINDOWS,
                                decimate=False)
    best = fit.noise
    if not best.mocap_correlated:
        return None
    white = [r for r in fit.candidates if r["time_constant_s"] == 0.0 and r["level"] == 1.0]
    chosen = min((r for r in fit.candidates if r["level"] == 1.0),
                 key=lambda r: r["minus_2_log_likelihood"])
    gain = (white[0]["minus_2_log_likelihood"] - chosen["minus_2_log_likelihood"]
            if white else float("nan"))
    return best, {"time_constant_s": best.mocap_noise_corr_time,
                  "fraction": best.mocap_noise_corr_fraction,
                  "minus_2_log_likelihood_gain_over_white": float(gain)}
