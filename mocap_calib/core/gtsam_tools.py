"""GTSAM plumbing: batched Python factors, the LM run, and covariances of combinations.

A GTSAM ``CustomFactor`` calls back into Python once per factor, and the calibration has
thousands of factors of the same kind. :class:`BatchFactors` makes each of them a real
``CustomFactor`` in the graph (so GTSAM's LM, robust noise models and marginals work as usual)
but evaluates them all in one vectorised numpy call: the first factor called at a new
linearisation point computes the whole batch, the others read their slice from the cache.
The cache is valid for values equal, key by key and bit for bit, to those it was computed at,
which is checked on every call (GTSAM hands each call its own copy of the values, so only their
content can tell).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.errors import ConvergenceError, ObservabilityError

Array = NDArray[np.float64]


@dataclass
class BatchOutput:
    """What a batch evaluation returns.

    Attributes:
        errors: per factor, the unwhitened error vector.
        jacobians: per factor, one matrix per key of that factor (in the factor's key order).
        loss_errors: per factor, the vector whose half squared norm (after the noise model)
            is the factor's cost, where that is not ``errors`` (a robust loss applied inside
            the factor, see :class:`Huber`); GTSAM asks for it when it wants no Jacobians.
    """

    errors: list[Array]
    jacobians: list[list[Array]]
    loss_errors: list[Array] | None = None


@dataclass
class BatchFactors:
    """A set of CustomFactors evaluated together.

    Args:
        evaluate: ``values -> BatchOutput`` for all factors at once.
        factor_keys: the keys of each factor (in the order of its Jacobians).
        noise: one noise model per factor, or one for all.
    """

    evaluate: Callable[[gtsam.Values], BatchOutput]
    factor_keys: list[list[int]]
    noise: Sequence[gtsam.noiseModel.Base] | gtsam.noiseModel.Base
    evaluations: int = 0
    seconds: float = 0.0
    _cache: BatchOutput | None = field(default=None, repr=False)
    _at: gtsam.Values | None = field(default=None, repr=False)  # where _cache was computed
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def output(self, values: gtsam.Values, i: int) -> tuple[Array, list[Array]]:
        """Error and Jacobians of factor ``i`` at ``values`` (evaluating the batch if needed)."""
        interrupt.check()
        return self._output(values, i)

    def _output(self, values: gtsam.Values, i: int) -> tuple[Array, list[Array]]:
        with self._lock:
            if interrupt.requested() and self._cache is not None:
                # Stopping: GTSAM only needs to return (see core/interrupt.py); zero errors
                # end its iteration at once and the check after it raises.
                return np.zeros_like(self._cache.errors[i]), self._cache.jacobians[i]
            # One C++ comparison (tolerance 0: exact, NaN equal to NaN), cheaper than a numpy
            # fingerprint of the factor's keys (4 us a call, 0.2 s of a 10-min run's stages 1-2).
            if self._cache is None or self._at is None or not values.equals(self._at, 0.0):
                t0 = time.perf_counter()
                self._cache = None  # not alive while the next one is computed
                self._cache = self.evaluate(values)
                self.seconds += time.perf_counter() - t0
                self.evaluations += 1
                self._at = gtsam.Values(values)
            return self._cache.errors[i], self._cache.jacobians[i]

    @property
    def evaluated_at(self) -> gtsam.Values | None:
        """The values of the cached evaluation (None: none cached)."""
        return self._at if self._cache is not None else None

    def invalidate(self) -> None:
        """Forget the cached evaluation (the factors changed without the values changing)."""
        with self._lock:
            self._cache = None

    def factors(self) -> list[gtsam.CustomFactor]:
        """The CustomFactors, to add to a graph."""
        out = []
        for i, keys in enumerate(self.factor_keys):
            nm = self.noise if isinstance(self.noise, gtsam.noiseModel.Base) else self.noise[i]

            @interrupt.called_from_native
            def fn(this: gtsam.CustomFactor, v: gtsam.Values, H: list | None, i: int = i) -> Array:
                err, jac = self._output(v, i)
                if H is None:  # GTSAM wants the cost (error()), not a linearisation
                    loss = self._cache.loss_errors if self._cache is not None else None
                    return err if loss is None else loss[i]
                for j, J in enumerate(jac):
                    H[j] = J
                return err

            out.append(gtsam.CustomFactor(nm, list(keys), fn))
        return out


@dataclass
class SolveReport:
    """Figures of one LM run.

    Attributes:
        converged: the cost stopped falling (relative decrease below the tolerance, or no
            decreasing step left at LM's largest damping); False when the iteration limit cut
            it off while it was still falling.
        reason: why it stopped, for messages.
        last_decrease: relative cost decrease of the last iteration.
    """

    iterations: int
    initial_error: float
    final_error: float
    seconds: float
    history: list[dict[str, object]] = field(default_factory=list)
    converged: bool = True
    reason: str = ""
    last_decrease: float = 0.0


#: Relative cost decrease per LM iteration below which a solve has converged (GTSAM also ends
#: an iteration whose best trial step changes the cost by less).
RELATIVE_TOL = 1e-7
#: Cost decrease per LM iteration below which a stage's solve has converged (the cost is half
#: a chi2, so this is statistically nothing): along a direction the data do not determine,
#: held only by a weak prior, LM would otherwise creep on for ever (a turntable's R_MI).
ABS_TOL = 5e-3
#: Predicted cost decrease of the next Gauss-Newton step below which a solve has converged
#: without trying it: the decrease is half the step's squared Mahalanobis length, so the step
#: would move no parameter by more than sqrt(2e-3) = 0.045 of its (statistical) sigma. Saves
#: the evaluation of a step that only confirms convergence (a window solve's: 1.1 s at 60 min).
PREDICTED_TOL = 1e-3
#: A solve is near its solution when the next Gauss-Newton step is predicted to lower the cost
#: by less than this (a step under 1.4 sigma); see ``run_lm``'s ``near_trials``.
NEAR_DECREASE = 1.0


def run_lm(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int = 50,
           on_iteration: Callable[[int, gtsam.Values, float], None] | None = None,
           relative_tol: float = RELATIVE_TOL, retry: bool = True, absolute_tol: float = 0.0,
           predicted_tol: float = 0.0, near_trials: int | None = None
           ) -> tuple[gtsam.Values, SolveReport]:
    """Levenberg-Marquardt with an optional per-iteration hook (values and error).

    A run cut off by the iteration limit while the cost still falls is retried once from where
    it stopped (with LM's damping reset, which is what usually stalls it); the report says
    whether the cost finally stopped falling (``converged``). With ``absolute_tol`` (see
    :data:`ABS_TOL`) it has also converged when an iteration lowers the cost by less; with
    ``predicted_tol`` (see :data:`PREDICTED_TOL`) when the next Gauss-Newton step would. With
    ``near_trials`` (and ``predicted_tol``) an iteration near the solution (see
    :data:`NEAR_DECREASE`) tries that many dampings, and the solve has converged when none
    lowers the cost: each trial is an evaluation, and LM raises its damping tenfold per failed
    one from where its successful steps left it (1e-7: ten trials before it damps at all).
    """
    t0 = time.perf_counter()
    initial_error = float(graph.error(initial))
    interrupt.check()
    tols = (relative_tol, absolute_tol, predicted_tol)
    values, it, err, rel, reason = _lm_pass(graph, initial, max_iterations, on_iteration,
                                            tols, 0, near_trials)
    if reason == "iteration limit" and retry:
        values, it2, err, rel, reason = _lm_pass(graph, values, max_iterations, on_iteration,
                                                 tols, it, near_trials)
        it += it2
    report = SolveReport(it, initial_error, float(err), time.perf_counter() - t0,
                         converged=reason != "iteration limit", reason=reason,
                         last_decrease=float(rel))
    return values, report


def _lm_pass(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int,
             on_iteration: Callable[[int, gtsam.Values, float], None] | None,
             tols: tuple[float, float, float], it0: int,
             near_trials: int | None = None
             ) -> tuple[gtsam.Values, int, float, float, str]:
    relative_tol, absolute_tol, predicted_tol = tols
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial,
                                            _lm_params(max_iterations, relative_tol))
    err = float(graph.error(initial))
    if on_iteration is not None and it0 == 0:
        on_iteration(0, initial, err)
    it = 0
    rel = 0.0
    reason = "iteration limit"
    while it < max_iterations:
        prev = err
        if predicted_tol > 0.0:
            predicted = predicted_decrease(graph, opt.values())
            if predicted < predicted_tol:
                reason = "converged"
                break
            if near_trials is not None and predicted < NEAR_DECREASE:
                lam = opt.lambda_()
                opt = gtsam.LevenbergMarquardtOptimizer(graph, opt.values(), _lm_params(
                    max_iterations, relative_tol, lam, lam * 10.0**near_trials))
        try:
            opt.iterate()
        except RuntimeError:  # the stop's zero errors can leave GTSAM nothing to solve
            interrupt.check()
            raise
        interrupt.check()  # a signal during the iteration only set the request
        it += 1
        err = float(opt.error())
        if on_iteration is not None:
            on_iteration(it0 + it, opt.values(), err)
        rel = (prev - err) / max(prev, 1e-300)
        if rel < relative_tol or err < 1e-12 or prev - err < absolute_tol:
            reason = "converged"
            break
        if opt.lambda_() > 1e10:
            reason = "no decreasing step at the largest damping"
            break
    return opt.values(), it, err, rel, reason


def _lm_params(max_iterations: int, relative_tol: float, damping: float = 1e-5,
               max_damping: float = 1e12) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_tol)
    params.setAbsoluteErrorTol(1e-12)
    params.setVerbosityLM("SILENT")
    # Marquardt's scaling: damping proportional to the Hessian's diagonal. The parameters'
    # scales differ by many orders (radians, metres, scale factors, seconds), so a plain
    # lambda * I either does nothing for some or freezes others.
    params.setDiagonalDamping(True)
    params.setlambdaInitial(damping)
    params.setlambdaUpperBound(max_damping)
    return params


def predicted_decrease(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    """The cost decrease the linearised cost at ``values`` predicts for the full Gauss-Newton
    step (an upper bound for LM's damped step); inf when the system cannot be solved (LM's
    own iteration then says why)."""
    lin = graph.linearize(values)
    interrupt.check()
    try:
        delta = lin.optimize()
    except RuntimeError:
        interrupt.check()
        return float("inf")
    return float(lin.error(gtsam.VectorValues.Zero(delta)) - lin.error(delta))


def require_converged(stage: str, report: SolveReport, max_iterations: int) -> None:
    """Raise :class:`ConvergenceError` (exit 4) naming the stage when its solve did not."""
    if report.converged:
        return
    raise ConvergenceError(
        f"the {stage} stage did not converge in {report.iterations} iterations (cost still "
        f"falling by {100 * report.last_decrease:.2g} % per iteration); raise "
        f"--max-iterations (now {max_iterations}) or check the inputs' units and conventions")


def marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Marginals:
    """GTSAM's marginals, with its indeterminate-system exception turned into a one-line
    :class:`~mocap_calib.errors.ObservabilityError`."""
    try:
        marg = gtsam.Marginals(graph, values)
    except RuntimeError as err:
        interrupt.check()
        raise gtsam_error(err) from None
    interrupt.check()
    return marg


def gtsam_error(err: RuntimeError) -> Exception:
    """A GTSAM exception as one line: an indeterminate linear system means the data (with the
    weak range priors) do not determine every parameter; anything else stays as it is."""
    text = " ".join(str(err).split())
    if "ndeterminant" not in text and "ndeterminate" not in text:
        return err
    return ObservabilityError(
        "the data do not determine every parameter (GTSAM: indeterminate linear system); the "
        "motion does not excite the model's parameters, or an input's unit or convention is "
        "wrong: check them, record motion about all axes, or use a smaller --model")


def information_matrix(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                       offsets: dict[int, int] | None = None, n: int | None = None):
    """Gauss-Newton information ``A^T A`` of the linearised graph as a sparse matrix.

    Returns ``(H, offsets, n)``: ``offsets[key]`` is the first row of the key's tangent block
    (keys in GTSAM's order), ``n`` the dimension. Given ``offsets`` and ``n`` (of a larger graph
    over the same values), the matrix uses that layout.
    """
    import scipy.sparse as sp

    gfg = graph.linearize(values)
    interrupt.check()
    if offsets is None:
        grad = gfg.gradientAtZero()  # one vector per key: gives each key's tangent dimension
        offsets, n = {}, 0
        for k in sorted(gfg.keys()):  # sparseJacobian_ orders columns by key
            offsets[k] = n
            n += int(np.asarray(grad.at(k)).shape[0])
        local = offsets
    else:
        # This graph's own column order: its keys, sorted, packed.
        grad = gfg.gradientAtZero()
        local, o = {}, 0
        for k in sorted(gfg.keys()):
            local[k] = o
            o += int(np.asarray(grad.at(k)).shape[0])
    ijs = np.asarray(gfg.sparseJacobian_())
    rows = ijs[0].astype(int) - 1
    cols = ijs[1].astype(int) - 1
    n_local = sum(int(np.asarray(grad.at(k)).shape[0]) for k in local)
    keep = cols < n_local  # the last column is the right-hand side
    remap = np.zeros(n_local, dtype=int)
    for k, o in local.items():
        d = int(np.asarray(grad.at(k)).shape[0])
        remap[o:o + d] = offsets[k] + np.arange(d)
    A = sp.csc_matrix((ijs[2][keep], (rows[keep], remap[cols[keep]])),
                      shape=(int(rows.max()) + 1, n))
    return (A.T @ A).tocsc(), offsets, n


def spd_factor(H):
    """Sparse factorisation of a symmetric positive-definite information matrix (``.solve``).

    A symmetric minimum-degree ordering without pivoting: scipy's default (COLAMD with partial
    pivoting) pivots off the diagonal of these matrices, whose variables differ in scale by
    decades, and fills the factor in. 60-min session (n = 4329, 112 000 nonzeros): 9.4
    million nonzeros in the factor, ~250 MB and 0.5 s, against 138 000 and 0.08 s; solutions
    agree to 4e-13.
    """
    from scipy.sparse.linalg import splu

    return splu(H.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True})


def linear_combination_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                                  combo: dict[int, Array]) -> Array:
    """Covariance of ``y = sum_k C_k dx_k`` (tangent-space increments of several keys).

    A joint marginal over many keys is dense and cubic in their number; this solves the sparse
    information system ``H z = C^T`` instead, linear in the length of a chain of keys.
    """
    H, offsets, n = information_matrix(graph, values)
    m = next(iter(combo.values())).shape[0]
    Ct = np.zeros((n, m))
    for k, Ck in combo.items():
        Ct[offsets[k]:offsets[k] + Ck.shape[1]] = Ck.T
    Z = spd_factor(H).solve(Ct)
    return Ct.T @ Z


def huber_weight(u: Array, k: float) -> Array:
    """Huber's weight at whitened error norms ``u``: 1 up to ``k``, ``k / u`` beyond."""
    return np.where(u <= k, 1.0, k / np.maximum(u, 1e-300))


@dataclass(frozen=True)
class Huber:
    """Huber's loss on the whitened error norm ``u = |e_i| / sigma_i`` of each of many small
    factors on the same keys, computed in numpy and handed to GTSAM as one stacked factor.

    It does what a GTSAM ``Robust(Huber(k), Isotropic(sigma_i))`` noise model on each factor
    does: the cost is the sum of ``rho(u) = u^2 / 2`` (``u <= k``), ``k u - k^2 / 2`` (beyond),
    and a linearisation scales each factor's whitened error and Jacobian by the square root of
    its weight ``w = min(1, k / u)``. As one factor, a stage of 20 000 keyframe intervals (60 min)
    costs GTSAM one callback per pass instead of 20 000 (10 min: stages 1-2 take 0.29 s, with a
    factor per interval 0.64 s).
    """

    sigmas: Array
    k: float
    dim: int = 3  # rows of each factor

    def weights(self, errors: Array) -> Array:
        """Every factor's robust weight at ``errors`` (n, d)."""
        return huber_weight(np.linalg.norm(errors, axis=1) / self.sigmas, self.k)

    def weights_and_chi2(self, errors: Array) -> tuple[Array, float]:
        """The weights and the weighted whitened cost (sum of ``w u^2``)."""
        w = self.weights(errors)
        return w, float(np.sum((errors / self.sigmas[:, None]) ** 2 * w[:, None]))

    def stacked(self, errors: Array, jacobians: Sequence[Array]) -> BatchOutput:
        """One factor (unit noise) from ``errors`` (n, d) and one Jacobian (n, d, dim) per
        key: whitened and weighted rows for a linearisation, and as its cost the rows whose
        half squared norm is ``rho(u)``."""
        e = errors / self.sigmas[:, None]
        u = np.linalg.norm(e, axis=1)
        out = u > self.k
        sw = np.sqrt(self.weights(errors))
        # rho(u) = (u f)^2 / 2 with f = sqrt(2 rho) / u: 1 inside the threshold.
        f = np.where(out, np.sqrt(np.maximum(2.0 * self.k * u - self.k**2, 0.0))
                     / np.where(out, u, 1.0), 1.0)
        scale = sw / self.sigmas
        return BatchOutput([(e * sw[:, None]).ravel()],
                           [[(J * scale[:, None, None]).reshape(-1, J.shape[2])
                             for J in jacobians]],
                           [(e * f[:, None]).ravel()])

    def factor(self, evaluate: Callable[[gtsam.Values], tuple[Array, list[Array]]],
               keys: list[int]) -> BatchFactors:
        """The stacked factor on ``keys`` of ``evaluate: values -> (errors, [Jacobian per
        key])``."""
        return BatchFactors(lambda v: self.stacked(*evaluate(v)), [keys],
                            gtsam.noiseModel.Unit.Create(len(self.sigmas) * self.dim))
