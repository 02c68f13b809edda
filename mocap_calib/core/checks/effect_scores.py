"""The effects the data show, tested cheaply at the solution: one evaluation of the window
factors with every canonical effect the model lacks added at zero, and a score (Lagrange
multiplier) test per effect.

For effect ``e`` (its parameters ``theta_e``, the others fixed at zero) the score is the
cost's gradient along ``theta_e`` with the model's own parameters re-optimised to first order:
``g_e = d_e - H_en H_nn^-1 d_n``, ``d`` the whitened ``J^T r`` and ``H`` the Gauss-Newton
information. Its variance is the information's Schur complement (model-based) or the spread of
the windows' own scores mapped the same way (a sandwich, windows as blocks: real residuals are
correlated and the noise model only approximately right); the smaller statistic of the two
counts. ``T = g^T V^-1 g`` is chi-square with ``dim(e)`` degrees of freedom under "no effect";
``V^-1 g`` is the effect's one-step estimate, judged by the plausibility limits the diagnosis
uses. An effect is listed as shown when it is significant at ``alpha`` (Bonferroni over the
candidates) and plausible.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.gtsam_tools import information_matrix, spd_factor
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, EFFECTS, Model
from mocap_calib.core.model.stats import chi2_isf, chi2_logsf, f_logsf
from mocap_calib.core.plausible import PlausibleLimits, effect_problem
from mocap_calib.core.position.graph import (
    PositionInit,
    Take,
    TakeStart,
    build_position_graph,
    key_knot,
)
from mocap_calib.core.position.stage import PositionResult
from mocap_calib.core.result.verdicts import EffectTest
from mocap_calib.core.uncertainty.sensitivity import correlated_mocap_model

Array = NDArray[np.float64]

#: Family-wise false-alarm rate over the candidates (Bonferroni).
ALPHA = 0.01
#: The tests evaluate every canonical effect's columns at once (3-4x a plain evaluation's
#: cost per window): beyond this many windows (20 min of 5 s windows) they use that many,
#: spread over the session. An effect that matters is shown long before (its statistic
#: grows with the data), and the tests' cost stays flat in the session's length (60 min:
#: 5.7 -> 2.2 s).
MAX_TEST_WINDOWS = 240


@dataclass(frozen=True)
class EffectScore:
    """One candidate's test; ``failures``: the statistics that could not be computed (the
    test then rests on the other one, or finds no evidence)."""

    effect: str
    statistic: float
    dof: int
    log10_p: float
    estimate: object  # the one-step estimate in the result file's form
    problem: str | None  # why it is implausible (None: plausible)
    significant: bool
    failures: tuple[str, ...] = ()
    #: The one-step estimate in the effect's own coordinates (a clock offset: every take's
    #: shift) and its model-based covariance (the Schur complement's inverse).
    step: Array = field(default_factory=lambda: np.zeros(0), repr=False, compare=False)
    step_cov: Array = field(default_factory=lambda: np.zeros((0, 0)), repr=False,
                            compare=False)
    #: The model-based statistic's log10 p alone (0: not computed): its ranking of strong
    #: effects follows their size, where the windows' (Hotelling's) tails flatten.
    model_log10_p: float = 0.0

    @property
    def shown(self) -> bool:
        return self.significant and self.problem is None

    def record(self) -> EffectTest:
        """The test as the result keeps it (figures rounded as the file shows them)."""
        return EffectTest(self.effect, round(self.statistic, 2), self.dof,
                          round(self.log10_p, 2), self.estimate, self.significant,
                          self.problem)


def effect_scores(pos: PositionResult, model: Model, limits: PlausibleLimits | None = None,
                  candidates: tuple[str, ...] | None = None,
                  alpha: float = ALPHA, sequential: bool = True,
                  parts: bool = False) -> list[EffectScore]:
    """Score tests of every canonical effect the model lacks (or ``candidates``): the
    effects shown in order of evidence (each tested with those before it free), then the
    rest (tested with the shown ones free). Without ``sequential``: every candidate tested
    against the model as it is, in order of evidence (the diagnosis adds one at a time and
    tests again). With ``parts``, the sandwich's blocks are the windows' one-second parts
    instead of the windows (Hotelling's statistic on a few windows has little power for an
    effect of several parameters: 12 windows, 9 parameters, F(9, 3)); the diagnosis, which
    confirms what it adds by a refit, tests so."""
    cands = [c for c in (candidates or CANONICAL_EFFECTS) if not model.has(c)]
    if not cands:
        return []
    # One linearisation per solution and candidate set: the calibration's tests and the
    # diagnosis' first step share it.
    H, d, by_window, by_part, rows_of = pos.memo.get(f"effect_scores {'+'.join(cands)}",
                                                      lambda: _linearise(pos, model, cands))
    rows = by_part if parts else by_window
    n = H.shape[0]
    alpha_each = alpha / len(cands)
    # In order of evidence, as the diagnosis adds effects: the strongest significant one is
    # then free (a nuisance) while the rest are tested again, so that a candidate that only
    # stands in for a stronger one is not listed.
    out: list[EffectScore] = []
    free: list[str] = []
    todo = list(cands)
    while todo:
        tests = []
        for c in todo:
            fixed = np.concatenate([rows_of[o] for o in todo])
            keep = np.setdiff1d(np.arange(n), np.setdiff1d(fixed, rows_of[c]))
            keep = np.setdiff1d(keep, rows_of[c])
            tests.append(_test(c, rows_of[c], keep, H, d, rows, alpha_each, limits))
        tests.sort(key=lambda t: t.log10_p)
        best = next((t for t in tests if t.shown), None) if sequential else None
        if best is None:
            out += tests
            break
        out.append(best)
        free.append(best.effect)
        todo.remove(best.effect)
    return out


def _linearise(pos: PositionResult, model: Model, cands: list[str]
               ) -> tuple[Array, Array, Array, Array, dict[str, NDArray[np.int64]]]:
    """The information, gradient and scores (per window, and per one-second part of a window)
    at the solution with the candidates added at zero, the windows' bias knots eliminated;
    and each candidate's rows."""
    ext = Model((*model.effects, *cands))
    which = _spread(pos)
    takes = [Take(t.s, t.windows.subset(w)) for t, w in zip(pos.takes, which, strict=True)]
    effects0 = {**pos.effects, **{e.name: e.zero() for e in ext.units
                                  if e.in_effects and e.name in cands}}
    init = PositionInit(pos.R_MI, pos.p_MI, pos.g_dir, pos.g_mag,
                        [TakeStart(t.delta, t.gyro_bias_mean, t.accel_bias_mean, t.knots[w])
                         for t, w in zip(pos.takes, which, strict=True)], effects0)
    # Under the correlated mocap noise the session prefers (when it does): a white model would
    # count correlated residuals as independent evidence for whatever can absorb them. The
    # solution's own noise model when it has a correlated part (identified from the data with
    # the IMU densities, or given); else the AR(1) model the windows' likelihood prefers.
    noise = pos.noise
    if not noise.mocap_correlated:
        corr = correlated_mocap_model(pos, model)
        noise = noise if corr is None else corr[0]
    pg = build_position_graph(takes, ext, noise, init)
    pg.set_weights([t.weights[w] for t, w in zip(pos.takes, which, strict=True)])
    for pp in pg.problems:
        pp.mocap_axis_scale = pos.axis_scale.copy()
    for pp in pg.problems:
        pp.collect_scores = True
    H, offsets, n = information_matrix(pg.graph, pg.values)
    grad = pg.graph.linearize(pg.values).gradientAtZero()
    d = np.zeros(n)
    for key, o in offsets.items():
        v = np.asarray(grad.at(key), dtype=float)
        d[o:o + len(v)] = -v  # gradientAtZero is that of 0.5 |A x - b|^2 at x = 0: -A^T b
    by_window, by_part = _window_scores(pg, offsets, n)
    # The windows' bias knots are nuisance in every test: eliminate them once (exact block
    # elimination with a sparse factor), so that each test solves a system of the shared
    # parameters only instead of a dense one over every knot (at 60 min, 4000+ of them).
    H, d, rows, index = _without_knots(H, d, np.vstack([by_window, by_part]),
                                       _knot_rows(pg, offsets))
    by_window, by_part = rows[:len(by_window)], rows[len(by_window):]
    by_part = by_part[np.any(by_part != 0.0, axis=1)]  # padding parts hold no samples
    return H, d, by_window, by_part, {c: index[_rows(pg, offsets, c)] for c in cands}


def windows_tested(pos: PositionResult) -> int:
    """How many of the session's windows the tests use (see :data:`MAX_TEST_WINDOWS`)."""
    return sum(len(w) for w in _spread(pos))


def _spread(pos: PositionResult) -> list[NDArray[np.int64]]:
    """Per take, the windows the tests use: all of them up to :data:`MAX_TEST_WINDOWS` in
    all, else that many spread evenly over every take (in proportion to its windows)."""
    counts = [t.windows.count for t in pos.takes]
    total = sum(counts)
    if total <= MAX_TEST_WINDOWS:
        return [np.arange(c) for c in counts]
    return [np.unique(np.linspace(0, c - 1, max(2, round(MAX_TEST_WINDOWS * c / total)))
                      .round().astype(np.int64)) for c in counts]


def _rows(pg: Any, offsets: dict[int, int], name: str) -> NDArray[np.int64]:
    """The information matrix rows of a candidate's parameters (a clock offset: every
    take's)."""
    rows = []
    for k in range(len(pg.takes)):
        key = pg.block_keys(k)[name]
        dim = EFFECTS[name].dim
        r = offsets[key] + np.arange(dim)
        if k == 0 or EFFECTS[name].acts_on == "clock":
            rows.append(r)
    return np.concatenate(rows)


def _knot_rows(pg: Any, offsets: dict[int, int]) -> NDArray[np.int64]:
    """The information matrix rows of every window's bias knot."""
    return np.concatenate([offsets[key_knot(pg.knot0[k] + w)] + np.arange(6)
                           for k, t in enumerate(pg.takes) for w in range(t.windows.count)])


def _without_knots(H: Any, d: Array, rows: Array, knots: NDArray[np.int64]
                   ) -> tuple[Array, Array, Array, NDArray[np.int64]]:
    """The information ``H`` (sparse), gradient ``d`` and window scores ``rows`` with the
    ``knots`` eliminated: every linear form ``v`` becomes ``v_S - H_SK H_KK^-1 v_K`` and the
    information its Schur complement, which leaves every score test unchanged. Returns them
    and the map from the full rows to the kept ones (-1: eliminated)."""
    n = H.shape[0]
    keep = np.setdiff1d(np.arange(n), knots)
    H = H.tocsc()
    Hkk = H[knots][:, knots].tocsc()
    Hks = H[knots][:, keep].toarray()
    X = spd_factor(Hkk).solve(np.column_stack([Hks, d[knots]]))
    Hss = H[keep][:, keep].toarray() - Hks.T @ X[:, :-1]
    index = np.full(n, -1)
    index[keep] = np.arange(len(keep))
    return (0.5 * (Hss + Hss.T), d[keep] - Hks.T @ X[:, -1],
            rows[:, keep] - rows[:, knots] @ X[:, :-1], index)


def _window_scores(pg: Any, offsets: dict[int, int], n: int) -> tuple[Array, Array]:
    """Every window's whitened score ``J^T r`` in the graph's coordinates (W, n), and every
    one-second part's (W x B, n; their sum over a window is the window's)."""
    layout = pg.problem.layout
    rows, parts = [], []
    for k, out in enumerate(pg.evals[-1]):
        keys = pg.block_keys(k)
        glob = np.concatenate([offsets[keys[name]] + np.arange(dim)
                               for name, dim in layout.blocks if name != "knot"])
        ts = out.extras.get("term_scores")
        for w, s in enumerate(out.scores):
            idx = np.concatenate([glob, offsets[key_knot(pg.knot0[k] + w)] + np.arange(6)])
            row = np.zeros(n)
            np.add.at(row, idx, s.sum(axis=0))
            part = np.zeros((s.shape[0], n))
            for b in range(s.shape[0]):
                np.add.at(part[b], idx, s[b])
            if ts is not None and w < len(ts):  # where the window's end meets the next knot
                nxt = np.concatenate([idx, offsets[key_knot(pg.knot0[k] + w + 1)] + np.arange(6)])
                end = np.zeros(n)
                np.add.at(end, nxt, ts[w])
                row += end
                used = np.flatnonzero(np.any(s != 0.0, axis=1))
                part[used[-1] if len(used) else -1] += end
            rows.append(row)
            parts.append(part)
    return np.array(rows), np.concatenate(parts)


def _test(name: str, e: NDArray[np.int64], n_idx: NDArray[np.int64], H: Array, d: Array,
          rows: Array, alpha: float, limits: PlausibleLimits | None) -> EffectScore:
    eff = EFFECTS[name]
    Hnn = H[np.ix_(n_idx, n_idx)]
    Hen = H[np.ix_(e, n_idx)]
    A = np.linalg.solve(Hnn, Hen.T).T  # H_en H_nn^-1
    g = d[e] - A @ d[n_idx]
    V_model = H[np.ix_(e, e)] - A @ Hen.T
    s = rows[:, e] - rows[:, n_idx] @ A.T
    n_w, k = len(s), len(e)
    log10_ps = []
    failures = []
    model_log10_p = 0.0
    try:  # model-based: chi-square
        log10_ps.append(float(chi2_logsf(float(g @ np.linalg.solve(V_model, g)), k)))
        model_log10_p = log10_ps[-1] / np.log(10.0)
    except np.linalg.LinAlgError as err:
        failures.append(f"the model-based statistic could not be computed ({err})")
    if n_w > k + 1:  # the windows' own spread: Hotelling's T^2 (few windows, F tails)
        S = np.cov(s, rowvar=False).reshape(k, k)
        try:
            t2 = float(g @ np.linalg.solve(n_w * S, g))  # n mean' S^-1 mean, g = n mean
            f = t2 * (n_w - k) / ((n_w - 1) * k)
            log10_ps.append(float(f_logsf(f, k, n_w - k)))
        except np.linalg.LinAlgError as err:
            failures.append(f"the windows' own statistic could not be computed ({err})")
    # The weaker evidence of the two counts.
    log10_p = max(log10_ps) / np.log(10.0) if log10_ps else 0.0
    T = float(chi2_isf(10.0**log10_p, k)) if log10_p > -300 else float("inf")
    step = np.linalg.solve(V_model, g)
    value = eff.report_value(step[:eff.dim] if eff.acts_on == "clock" else step)
    problem = effect_problem(name, value, limits or PlausibleLimits())
    return EffectScore(name, float(T), k, float(log10_p), _plain(value), problem,
                       bool(log10_p < np.log10(alpha)), tuple(failures), step,
                       np.linalg.inv(V_model), float(model_log10_p))


def _plain(value: object) -> object:
    """Numbers as plain floats (for the result file)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return np.asarray(value, dtype=float).tolist()
    return float(value)  # type: ignore[arg-type]
