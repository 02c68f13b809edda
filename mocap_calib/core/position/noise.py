"""The session's noise model, identified from its own data.

A drone in flight is not its data sheet: the rotors shake the accelerometer (EuRoC V2_03: 15
times its density against the Vicon), the pose solver smooths and the marker sets change, so
the mocap noise is correlated over a fraction of a second. The answer depends on how the
accelerometer is weighted against the mocap, so the weights must be the data's own.

Every level is identified jointly by the windows' exact Gaussian likelihood (the window filter
of :mod:`mocap_calib.core.position.engine`) at the current solution: the accelerometer's and the
gyro's white-noise densities, the mocap's attitude and position levels, the time constant and
fraction of its correlated (AR(1)) part; then the accelerometer's level per IMU axis (the rotors
shake a drone hardest along its thrust axis), kept where the data show it; then the bias random
walks with the white densities they trade with (a random walk given 3x too high took two thirds
of the accelerometer's white level when it was held). Jointly, because each level can pass for
another: a white mocap model absorbs an accelerometer too noisy for its density (the position
level grows tenfold), and a white accelerometer level absorbs correlated mocap noise. The
likelihood separates them (the accelerometer's error grows with the time since a window's start,
correlated mocap noise does not), and a simulated flight's true levels are found within a few
per cent (``tests/test_noise_identification.py``).

The search runs on a subset of the windows, spread over every take and thinned to about
:data:`RATE_HZ` (the per-sample mocap noise and the correlation time mean the same at any
rate; every IMU sample between the kept poses is still integrated): a coarse grid chooses the
start, then Newton steps on a quadratic model of ``-2 log L`` in the log-levels, its gradient
and Hessian from one batch of likelihood passes around the current point (the trajectory is
integrated once per batch, only the filter runs per candidate). A weak prior on the IMU
densities and random walks, centred on the ones given, keeps a level the data cannot see (the
gyro's, when the mocap attitude noise dominates) where it was given.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.model.stats import chi2_ppf
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.engine import PositionProblem, Theta

Array = NDArray[np.float64]

#: The identified parameters: log densities (accel, gyro), log mocap sigmas (position,
#: attitude), log correlation time, logit of the correlated fraction, and the log of the
#: accelerometer's variance factors on its x and y axes (z: what keeps their product one).
PARAMETERS = ("accelerometer_noise_density", "gyroscope_noise_density",
              "mocap_position_sigma", "mocap_rotation_sigma", "mocap_noise_corr_time",
              "mocap_noise_corr_fraction", "accelerometer_axis_scale_x",
              "accelerometer_axis_scale_y", "accelerometer_random_walk",
              "gyroscope_random_walk")
#: The levels searched first, then the accelerometer's axes (with its level).
LEVELS = (0, 1, 2, 3, 4, 5)
AXES = (0, 6, 7)
#: Then the bias random walks with the white densities they trade with.
WALKS = (0, 1, 8, 9)
#: The accelerometer's per-axis levels are kept when they lower -2 log L beyond the
#: chi-square quantile of this tail probability.
AXES_ALPHA = 1e-3
#: Windows the likelihood is evaluated on, spread over every take.
MAX_WINDOWS = 8
#: Mocap rate (Hz) the windows are thinned to for the search.
RATE_HZ = 25.0
#: Bounds of the correlation time (s) and fraction.
CORR_TIME_RANGE = (0.01, 5.0)
CORR_FRACTION_RANGE = (0.02, 0.995)
#: The accelerometer's per-axis variance factors stay within exp(+-this) of their mean.
AXIS_RANGE = float(np.log(30.0))
#: The IMU densities' prior: a factor of this on either side of the given one is one sigma.
PRIOR_FACTOR = 10.0
#: Newton iterations at most; the search ends when -2 log L improves by less than
#: :data:`SETTLED` (a likelihood-ratio statistic: far below any difference the answer feels).
MAX_ITERATIONS = 10
SETTLED = 2.0
#: Step of the finite differences in the log-parameters, and the largest Newton step.
STEP = 0.3
MAX_STEP = 1.5
#: The data contradict the given densities when identifying the levels lowers -2 log L by
#: more than the chi-square quantile of this tail probability (6 degrees of freedom).
CONTRADICTION_ALPHA = 1e-6


@dataclass(frozen=True)
class NoiseIdentification:
    """The noise model the data prefer, against the one the fit used before.

    Attributes:
        noise: the identified model (IMU densities, mocap levels, correlation); the random
            walks stay as given.
        start: the model it was compared with (given densities, mocap levels from the
            residuals).
        gain: ``-2 log L`` of ``start`` minus that of ``noise`` on the search's windows
            (positive: the identified model fits better).
        threshold: the gain beyond which the given densities are contradicted.
        evaluations: likelihood passes the search took.
        windows: windows (and samples) it ran on.
    """

    noise: NoiseModel
    start: NoiseModel
    gain: float
    threshold: float
    evaluations: int
    windows: int
    samples: int

    @property
    def contradicts(self) -> bool:
        """Whether the data contradict the start model (the identified one is then used)."""
        return self.gain > self.threshold


def search_problems(problems: list[tuple[PositionProblem, Theta]],
                    max_windows: int = MAX_WINDOWS) -> list[tuple[PositionProblem, Theta]]:
    """Each take's problem cut to its share of ``max_windows`` windows spread over it, thinned
    to about :data:`RATE_HZ`."""
    total = sum(pp.win.count for pp, _ in problems)
    out = []
    for pp, th in problems:
        share = max(3, int(round(max_windows * pp.win.count / max(total, 1))))
        rate = 1.0 / float(np.median(np.diff(pp.win.tau[0][pp.win.mask[0]])))
        out.append(pp.spread(th, share, max(1, int(rate // RATE_HZ))))
    return out


class _Objective:
    """``-2 log L`` over every take's search windows, plus the IMU densities' prior, for
    batches of parameter vectors (one likelihood pass per candidate)."""

    def __init__(self, problems: list[tuple[PositionProblem, Theta]], base: NoiseModel,
                 given: NoiseModel) -> None:
        self.problems = problems
        self.base = base
        self.centre = np.log([given.accelerometer_noise_density,
                              given.gyroscope_noise_density, given.accelerometer_random_walk,
                              given.gyroscope_random_walk])
        self.evaluations = 0

    def noise(self, x: Array) -> NoiseModel:
        T = float(np.clip(np.exp(x[4]), *CORR_TIME_RANGE))
        rho = float(np.clip(1.0 / (1.0 + np.exp(-x[5])), *CORR_FRACTION_RANGE))
        axes = np.clip(np.array([x[6], x[7], -x[6] - x[7]]), -AXIS_RANGE, AXIS_RANGE)
        return replace(self.base, accelerometer_noise_density=float(np.exp(x[0])),
                       gyroscope_noise_density=float(np.exp(x[1])),
                       mocap_position_sigma=float(np.exp(x[2])),
                       mocap_rotation_sigma=float(np.exp(x[3])),
                       mocap_noise_corr_time=T, mocap_noise_corr_fraction=rho,
                       accelerometer_axis_scale=tuple(float(np.exp(a)) for a in axes),
                       accelerometer_random_walk=float(np.exp(x[8])),
                       gyroscope_random_walk=float(np.exp(x[9])))

    def __call__(self, xs: list[Array]) -> Array:
        return self.likelihood([self.noise(x) for x in xs]) + np.array(
            [self.prior(x) for x in xs])

    def likelihood(self, models: list[NoiseModel]) -> Array:
        interrupt.check()
        total = np.zeros(len(models))
        for pp, th in self.problems:
            for i, (chi2, logdet) in enumerate(pp.likelihoods(th, models)):
                total[i] += float(chi2.sum() + logdet.sum())
        self.evaluations += len(models)
        return total

    def prior(self, x: Array) -> float:
        imu = np.r_[x[0:2], x[8:10]]
        return float(np.sum(((imu - self.centre) / np.log(PRIOR_FACTOR)) ** 2))


def to_vector(nz: NoiseModel) -> Array:
    """The search's parameters of a noise model (a white one starts at a weak correlation)."""
    T = float(np.clip(nz.mocap_noise_corr_time or 0.1, *CORR_TIME_RANGE))
    rho = float(np.clip(nz.mocap_noise_corr_fraction or 0.3, *CORR_FRACTION_RANGE))
    axes = np.log(np.asarray(nz.accelerometer_axis_scale, dtype=float))
    axes -= axes.mean()
    return np.array([np.log(nz.accelerometer_noise_density), np.log(nz.gyroscope_noise_density),
                     np.log(nz.mocap_position_sigma), np.log(nz.mocap_rotation_sigma),
                     np.log(T), np.log(rho / (1.0 - rho)), axes[0], axes[1],
                     np.log(nz.accelerometer_random_walk), np.log(nz.gyroscope_random_walk)])


def identify_noise(problems: list[tuple[PositionProblem, Theta]], start: NoiseModel,
                   given: NoiseModel, warm: NoiseModel | None = None) -> NoiseIdentification:
    """The noise model the windows' likelihood prefers at the given parameters.

    Args:
        problems: every take's position problem (its weights and mocap axis shape as fitted)
            with the parameters to evaluate at.
        start: the model the fit used (its mocap levels from the residuals).
        given: the densities the user gave (the prior's centre).
        warm: an earlier identification's model to start from (skips the grid).
    """
    sub = search_problems(problems)
    f = _Objective(sub, start, given)
    f0 = float(f.likelihood([start])[0])
    x = to_vector(warm) if warm is not None else _grid_start(f, start, given)
    x, fx = _newton(f, x, LEVELS)
    x_axes, f_axes = _newton(f, x, AXES)
    # Per-axis levels only where the data show them (a likelihood-ratio test on their 2
    # degrees of freedom): a few windows give each axis's variance a scatter of its own.
    if fx - f_axes > float(chi2_ppf(1.0 - AXES_ALPHA, 2)):
        x = x_axes
    x, fx = _newton(f, x, WALKS)
    best = f.noise(x)
    gain = f0 - float(f.likelihood([best])[0])
    return NoiseIdentification(
        noise=best, start=start, gain=gain,
        threshold=float(chi2_ppf(1.0 - CONTRADICTION_ALPHA, len(PARAMETERS))),
        evaluations=f.evaluations, windows=sum(pp.win.count for pp, _ in sub),
        samples=int(sum(pp.win.mask.sum() for pp, _ in sub)))


def _grid_start(f: _Objective, start: NoiseModel, given: NoiseModel) -> Array:
    """The best of a coarse grid: the accelerometer at 1-30x its given density, the mocap's
    position level as given and from the residuals, white or correlated."""
    cands = []
    for factor in (1.0, 3.0, 10.0, 30.0):
        for sp in sorted({given.mocap_position_sigma, start.mocap_position_sigma}):
            for T, rho in ((0.1, 0.3), (0.3, 0.9)):
                nz = replace(start, accelerometer_noise_density=(
                    given.accelerometer_noise_density * factor), mocap_position_sigma=sp,
                    mocap_noise_corr_time=T, mocap_noise_corr_fraction=rho)
                cands.append(to_vector(nz))
    v = f(cands)
    return cands[int(np.argmin(v))]


def _newton(f: _Objective, x: Array, active: tuple[int, ...]) -> tuple[Array, float]:
    """Damped Newton steps on the ``active`` parameters, on a quadratic model of ``f`` from
    finite differences (one batch per step: the point, two per parameter, one per pair), each
    checked along its line."""
    n = len(active)
    pairs = list(itertools.combinations(range(n), 2))
    h = STEP
    fx = float("inf")
    for _ in range(MAX_ITERATIONS):
        pts = [x.copy()]
        for i in active:
            for s in (1.0, -1.0):
                p = x.copy()
                p[i] += s * h
                pts.append(p)
        for a, b in pairs:
            p = x.copy()
            p[active[a]] += h
            p[active[b]] += h
            pts.append(p)
        v = f(pts)
        f0 = float(v[0])
        fp, fm = v[1:2 * n + 1:2], v[2:2 * n + 2:2]
        g = (fp - fm) / (2.0 * h)
        H = np.diag((fp - 2.0 * f0 + fm) / h**2)
        for k, (a, b) in enumerate(pairs):
            H[a, b] = H[b, a] = (v[2 * n + 1 + k] - fp[a] - fp[b] + f0) / h**2
        w, V = np.linalg.eigh(H)
        # An indefinite model (far from the optimum) steps by the curvatures' magnitudes.
        w = np.maximum(np.abs(w), 1e-6 * float(np.max(np.abs(w))) + 1e-12)
        step = -V @ ((V.T @ g) / w)
        step *= min(1.0, MAX_STEP / max(float(np.max(np.abs(step))), 1e-300))
        full = np.zeros_like(x)
        full[list(active)] = step
        trial = [x + a * full for a in (1.0, 0.5, 0.25)]
        vt = f(trial)
        b = int(np.argmin(vt))
        if vt[b] < f0:
            x, fx = trial[b], float(vt[b])
            if f0 - fx < SETTLED:
                break
        else:  # no better point along the step: a finer model, or done
            fx = f0
            h *= 0.5
            if h < STEP / 8.0:
                break
    return x, fx
