"""Uncertainty of the position stage: marginal covariances, every take's session-mean bias,
and which parameters the data did not determine.

Two covariances are computed. The model-based one (``H^-1``, GTSAM's marginals) is right when
the noise model is. The sandwich ``H^-1 B H^-1`` takes the spread of the data's own scores
instead: ``B`` sums, over the windows, the outer products of each window's whitened score
``J^T r`` (its end rows, where the window's end bias meets the next knot, included), plus the
information of the factors that are not data (priors).
A window is a block of at least five seconds: longer than the correlation of real mocap noise
(vibration, marker-body flex), and its diffuse start makes windows nearly independent (a
session of fewer than :data:`MIN_BLOCKS` windows uses their one-second parts instead). When
the model is right, ``B`` estimates ``H`` and both agree; when the residuals hold structure the
model lacks, the windows' scores scatter more than the model says and the sandwich grows with
them. The statistical sigma of every component is the larger of the two.
A take's session-mean bias is judged against the bias's time mean (see :mod:`.session_mean`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.gtsam_tools import information_matrix, marginals, spd_factor
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GYRO_BIAS,
    RANGE_SIGMA,
    TIME_OFFSET,
    UNOBSERVABLE_RATIO,
)
from mocap_calib.core.position.graph import key_knot, key_time
from mocap_calib.core.position.session_mean import SessionMean, knot_weights
from mocap_calib.core.position.windows import Windows

Array = NDArray[np.float64]

#: Fewest blocks of the sandwich: with fewer windows (a short session) the windows' one-second
#: sub-blocks are the blocks instead, or the meat would rest on a handful of outer products.
MIN_BLOCKS = 10


@dataclass
class TakeUncertainty:
    """One take's own covariances: ``time_offset`` (when estimated), ``gyro_bias`` and
    ``accel_bias`` (of the take's session-mean bias against the bias's mean over time, when
    computed; else of the knots' mean), the knots' 1-sigma and the mean bias; ``cov_knots``:
    the biases' as the knots' mean's own (how it moves by chance between fits of one
    session's data)."""

    cov: dict[str, Array]
    knot_sigma: Array
    bias_mean: Array
    cov_knots: dict[str, Array] = field(default_factory=dict)


@dataclass
class PositionUncertainty:
    """Covariances at the solution.

    Attributes:
        cov: per shared parameter block, its covariance (tangent space).
        takes: every take's own.
        cov_model: the model-based covariances of every block (the first take's own blocks
            under their names), before the sandwich.
        robust_ratio: per block, the sandwich's sigma over the model's, per component.
    """

    cov: dict[str, Array]
    takes: list[TakeUncertainty]
    cov_model: dict[str, Array] = field(default_factory=dict)
    robust_ratio: dict[str, list[float]] = field(default_factory=dict)


@dataclass(frozen=True)
class CovarianceInputs:
    """What :func:`position_covariances` needs of the stage.

    Attributes:
        shared_keys: shared block name -> key.
        blocks: (name, dim) of a window's Jacobian columns in order, the knot excluded.
        windows: every take's windows; knot0: every take's first knot index.
        knots: every take's (W, 6) knots.
        means: every take's session-mean bias against the bias's mean over time (see
            :mod:`.session_mean`); None: the biases' covariance is the knots' mean's own.
        timed: the model estimates each take's clock offset.
        scores: every take's (W, B, p) per-window-and-block whitened scores, or None.
        window_blocks: the sandwich's blocks are whole windows when there are enough of them
            (see MIN_BLOCKS); False: always their one-second parts.
    """

    shared_keys: dict[str, int]
    blocks: list[tuple[str, int]]
    windows: list[Windows]
    knot0: list[int]
    knots: list[Array]
    means: list[SessionMean] | None
    timed: bool
    scores: list[Array] | None = None
    window_blocks: bool = True
    #: every take's (W-1, p+6) scores of the rows where a window's end meets the next knot
    term_scores: list[Array | None] | None = None


def position_covariances(graph: gtsam.NonlinearFactorGraph, sol: gtsam.Values,
                         inp: CovarianceInputs) -> PositionUncertainty:
    """Marginals of every shared block, every take's clock offset, knots and session-mean
    bias; with the scores, the sandwich too (the larger of the two per component)."""
    marg = marginals(graph, sol)
    cov = {name: np.asarray(marg.marginalCovariance(key))
           for name, key in inp.shared_keys.items()}
    takes: list[TakeUncertainty] = []
    H, offsets, n = information_matrix(graph, sol)
    combos = [_bias_columns(inp, k, offsets, n) for k in range(len(inp.windows))]
    lu = spd_factor(H)
    for k, (win, k0) in enumerate(zip(inp.windows, inp.knot0, strict=True)):
        C = combos[k]
        V = C.T @ lu.solve(C)
        # The knots' mean's own; against the bias's time mean: its posterior (the parameters'
        # part through its Jacobian, the integrals' own given them) and the reported mean's
        # distance from it.
        knots_cov = _bias_blocks(V[0:6, 0:6])
        own = dict(knots_cov) if inp.means is None else _bias_blocks(V[6:12, 6:12]
                                                                     + _given(inp, k))
        if inp.timed:
            own[TIME_OFFSET.name] = np.asarray(marg.marginalCovariance(key_time(k)))
        knot_sigma = np.stack([np.sqrt(np.diag(marg.marginalCovariance(key_knot(k0 + w))))
                               for w in range(win.count)])
        mean = knot_weights(win) @ inp.knots[k]
        takes.append(TakeUncertainty(own, knot_sigma, mean, knots_cov))
    cov_model = {**cov, **takes[0].cov}
    unc = PositionUncertainty(cov, takes, cov_model, {})
    if inp.scores is not None:
        _with_sandwich(unc, graph, sol, inp, combos, (H, offsets, n, lu))
    return unc


def _bias_blocks(V: Array) -> dict[str, Array]:
    return {GYRO_BIAS.name: V[0:3, 0:3], ACCEL_BIAS.name: V[3:6, 3:6]}


def _given(inp: CovarianceInputs, take: int) -> Array:
    """What the session mean's covariance against the time mean adds to its parameters' part:
    the filters' integrals' own covariance, and the reported mean's distance from the
    posterior mean."""
    assert inp.means is not None
    sm = inp.means[take]
    d = sm.knots_mean(inp.knots[take]) - sm.value(inp.knots[take])
    return sm.cov_given + np.outer(d, d)


def _bias_columns(inp: CovarianceInputs, take: int, offsets: dict[int, int], n: int) -> Array:
    """(n, 6) or (n, 12): the knots' mean's derivative by every variable of the graph, then
    (with the time means) the time mean's."""
    E = np.zeros((n, 6))
    c = knot_weights(inp.windows[take])
    for w in range(inp.windows[take].count):
        o = offsets[key_knot(inp.knot0[take] + w)]
        E[o:o + 6] = c[w] * np.eye(6)
    if inp.means is None:
        return E
    return np.concatenate([E, _mean_columns(inp, take, offsets, n)], axis=1)


def _window_columns(inp: CovarianceInputs, take: int, offsets: dict[int, int]) -> list[Array]:
    """Per window of ``take``, the global indices of its Jacobian's columns (layout order, its
    knot last)."""
    keys = {**inp.shared_keys, **({TIME_OFFSET.name: key_time(take)} if inp.timed else {})}
    glob = np.concatenate([offsets[keys[name]] + np.arange(d) for name, d in inp.blocks])
    k0 = inp.knot0[take]
    return [np.concatenate([glob, offsets[key_knot(k0 + w)] + np.arange(6)])
            for w in range(inp.windows[take].count)]


def _mean_columns(inp: CovarianceInputs, take: int, offsets: dict[int, int], n: int) -> Array:
    """(n, 6) the derivative of the session's time-mean bias (its posterior mean) by every
    variable of the graph."""
    assert inp.means is not None
    sm, k0 = inp.means[take], inp.knot0[take]
    E = np.zeros((n, 6))
    for w, idx in enumerate(_window_columns(inp, take, offsets)):
        E[idx] += sm.d_window[w].T
        if w + 1 < inp.windows[take].count:
            nxt = offsets[key_knot(k0 + w + 1)]
            E[nxt:nxt + 6] += sm.d_next[w].T
    return E


def _with_sandwich(unc: PositionUncertainty, graph: gtsam.NonlinearFactorGraph,
                   sol: gtsam.Values, inp: CovarianceInputs,
                   combos: list[Array], lin: tuple) -> None:
    """``H^-1 B H^-1`` for every block, raised to where it exceeds the model's (in place)."""
    H, offsets, n, lu = lin
    n_windows = sum(w.count for w in inp.windows)
    other = gtsam.NonlinearFactorGraph()
    for i in range(n_windows, graph.size()):
        other.add(graph.at(i))
    H_other, _, _ = information_matrix(other, sol, offsets, n)
    E, dims = _targets(inp, offsets, n, combos)
    Z = lu.solve(E)
    meat = Z.T @ (H_other @ Z)
    T = _score_rows(inp, offsets, Z, whole=inp.window_blocks and n_windows >= MIN_BLOCKS)
    if len(T) > 1:  # centred: a refit near (not at) its optimum keeps its mean out of B
        T = (T - T.mean(axis=0)) * np.sqrt(len(T) / (len(T) - 1.0))
    meat += T.T @ T
    o = 0
    robust: dict[str, Array] = {}
    for name, d in dims:
        robust[name] = meat[o:o + d, o:o + d]
        o += d
    unc.cov, unc.robust_ratio = _larger(unc.cov, robust)
    for k, tu in enumerate(unc.takes):
        r = {}
        if inp.timed:
            r[TIME_OFFSET.name] = meat[o:o + 1, o:o + 1]
            o += 1
        # The windows' end rows carry the wander between knots: no bridge term; the
        # integrals' own covariance and the reported mean's distance are not the scores'.
        r_knots = _bias_blocks(meat[o:o + 6, o:o + 6])
        o += 6
        tu.cov_knots, _ = _larger(tu.cov_knots, r_knots)
        if inp.means is None:
            r.update(r_knots)
        else:
            r.update(_bias_blocks(meat[o:o + 6, o:o + 6] + _given(inp, k)))
            o += 6
        tu.cov, ratio = _larger(tu.cov, r)
        if k == 0:
            unc.robust_ratio.update(ratio)


def _targets(inp: CovarianceInputs, offsets: dict[int, int], n: int,
             combos: list[Array]) -> tuple[Array, list[tuple[str, int]]]:
    """The columns the sandwich is wanted for: every shared block's components, then per take
    its clock offset and mean bias (the knots' mean, then the time mean when computed). Returns
    them and the shared blocks' (name, dim)."""
    dims = dict(inp.blocks)
    shared = [(name, dims[name]) for name in inp.shared_keys]
    parts = []
    for name, d in shared:
        e = np.zeros((n, d))
        e[offsets[inp.shared_keys[name]] + np.arange(d), np.arange(d)] = 1.0
        parts.append(e)
    for k in range(len(inp.windows)):
        if inp.timed:
            e = np.zeros((n, 1))
            e[offsets[key_time(k)], 0] = 1.0
            parts.append(e)
        parts.append(combos[k])
    return np.concatenate(parts, axis=1), shared


def _score_rows(inp: CovarianceInputs, offsets: dict[int, int], Z: Array,
                whole: bool) -> Array:
    """Every block's whitened score mapped to the targets: a block is a window (``whole``) or
    one of its one-second parts."""
    rows = []
    for k, (sc, k0) in enumerate(zip(inp.scores or [], inp.knot0, strict=True)):
        cols = _window_columns(inp, k, offsets)
        ts = None if inp.term_scores is None else inp.term_scores[k]
        for w in range(sc.shape[0]):
            idx = cols[w]
            end = None
            if ts is not None and w < len(ts):
                nxt = np.concatenate([idx, offsets[key_knot(k0 + w + 1)] + np.arange(6)])
                end = ts[w] @ Z[nxt]
            if whole:
                rows.append(sc[w].sum(axis=0) @ Z[idx] + (0.0 if end is None else end))
            else:
                part = sc[w] @ Z[idx]
                if end is not None:  # the end rows belong to the window's last part
                    used = np.flatnonzero(np.any(sc[w] != 0.0, axis=1))
                    part[used[-1] if len(used) else -1] += end
                rows.extend(part)
    T = np.array(rows)
    return T[np.any(T != 0.0, axis=1)]  # padding blocks of short windows hold no samples


def _larger(model: dict[str, Array], robust: dict[str, Array]
            ) -> tuple[dict[str, Array], dict[str, list[float]]]:
    """Per block: the model covariance with each component's variance raised to the sandwich's
    where that is larger (correlations kept), and the sigma ratios sandwich / model."""
    out, ratio = {}, {}
    for name, C in model.items():
        if name not in robust:
            out[name] = C
            continue
        v_m = np.maximum(np.diag(C), 1e-300)
        r = np.sqrt(np.maximum(np.diag(robust[name]), 0.0) / v_m)
        s = np.maximum(1.0, r)
        out[name] = C * np.outer(s, s)
        ratio[name] = [round(float(x), 3) for x in r]
    return out, ratio


def unobservable_blocks(cov: dict[str, Array]) -> dict[str, str]:
    """Blocks whose posterior sigma is not well below their range prior, with the reason."""
    unobservable: dict[str, str] = {}
    for name, C in cov.items():
        prior_sig = RANGE_SIGMA.get(name)
        if prior_sig is None:
            continue
        sig = np.sqrt(np.maximum(np.diag(C), 0.0))
        bad = sig > UNOBSERVABLE_RATIO * prior_sig
        if np.any(bad):
            axes = ", ".join(str(i) for i in np.flatnonzero(bad))
            unobservable[name] = (f"not determined by the motion (component {axes}: sigma "
                                  f"{sig[bad].max():.3g} vs prior range {prior_sig:.3g}); "
                                  "excite it more or give a prior")
    return unobservable
