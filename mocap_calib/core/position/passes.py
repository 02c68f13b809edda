"""The window filter pass, compiled: every window's samples, :data:`~.kernels.LANES` windows at
a time (see :mod:`mocap_calib.core.position.engine` for the model, :mod:`.kalman` for the calls
and :mod:`.kernels` for the algebra).

Per sample the pass propagates the nominal trajectory's sensitivities ``S`` (rows 0:9 of ``Y``)
and the filter state (mean ``X`` for every column of ``[J | r]``, covariance ``P``) through the
step's error-state transition, whitens the sample's residual rows with the Cholesky factor of the
innovation covariance and sums the Gram matrix, the scores and the likelihood's parts. Windows
shorter than others of their group run on with empty (masked) samples.

Layouts: ``inc`` (W, m, 51) holds a step's packed increments (:data:`~.kernels.N_INC`),
``Rbar`` (W, m+1, 3, 3) the nominal attitudes, ``par`` the noise (:func:`.kalman.noise_params`).
"""

from __future__ import annotations

import numpy as np

from mocap_calib.core.jit import kernel
from mocap_calib.core.position.kernels import (
    DIFFUSE,
    LANES,
    N_INC,
    Q_ACCEL,
    Q_ACCEL_WALK,
    Q_GYRO,
    Q_GYRO_WALK,
    RHO,
    SIG2,
    T_CORR,
    cholesky6,
    forward,
    gain_update,
    lever,
    mocap_cov,
    phi_rows,
    predict_cov,
    transition_blocks,
)

# ruff: noqa: N803, N806  (matrix names)


@kernel
def lanes_of(W, g, lane):  # pragma: no cover  (compiled)
    """Windows of group ``g`` into ``lane`` (the last real one where the group runs out);
    returns how many are real."""
    n = 0
    for v in range(LANES):
        w = g * LANES + v
        lane[v] = min(w, W - 1)
        n += w < W
    return n


@kernel
def gather_op(j, lane, inc, Rbar, incL, RkL):  # pragma: no cover  (compiled)
    """Step ``j``'s increments and nominal attitudes of every lane."""
    for v in range(LANES):
        w = lane[v]
        for a in range(N_INC):
            incL[a, v] = inc[w, j, a]
        for a in range(3):
            for b in range(3):
                RkL[a, b, v] = Rbar[w, j, a, b]


@kernel
def gather_step(j, lane, h, inc, Rbar, dwf, hk, incL, RkL, dwfL):  # pragma: no cover
    """Step ``j``'s inputs of every lane: lengths, increments, nominal attitudes and the
    parameters' inputs ``d(w, f)/dtheta``."""
    gather_op(j, lane, inc, Rbar, incL, RkL)
    for v in range(LANES):
        w = lane[v]
        hk[v] = h[w, j]
        for a in range(6):
            for c in range(dwf.shape[3]):
                dwfL[a, c, v] = dwf[w, j, a, c]


@kernel
def gather_sample(k, lane, n_real, mask, wts, op_wts, r, Jinv, Pm_rot, R_WM, ok, wt, owt, rL,
                  JL, PL, RL):  # pragma: no cover  (compiled)
    """Sample ``k``'s inputs of every lane; returns whether any lane has a real sample."""
    any_ok = False
    for v in range(LANES):
        w = lane[v]
        real = v < n_real and mask[w, k]
        ok[v] = 1.0 if real else 0.0
        any_ok = any_ok or real
        wt[v] = wts[w, k]
        owt[v] = op_wts[w, k]
        for a in range(6):
            rL[a, v] = r[w, k, a]
        for a in range(3):
            for b in range(3):
                JL[a, b, v] = Jinv[w, k, a, b]
                PL[a, b, v] = Pm_rot[w, k, a, b]
                RL[a, b, v] = R_WM[w, k, a, b]
    return any_ok


@kernel
def start_group(Y, X, P, p, ns, rs, ts, R0, M_op, Lk, sig2, rho, cov):  # pragma: no cover
    """The windows' start: the diffuse prior, the AR(1) states' stationary covariance, the
    sensitivities of the start pose to ``R_MI`` and ``p_MI``."""
    Y[:, :, :] = 0.0
    X[:, :, :] = 0.0
    P[:, :, :] = 0.0
    for i in range(3):
        for j in range(3):
            P[3 * j + i, 3 * j + i, :] = DIFFUSE[j] ** 2
        if p > 0:
            Y[i, rs + i, :] = 1.0
            for j in range(3):
                Y[3 + i, ts + j, :] = R0[i, j, :]
    lever(R0, M_op, Lk)
    if ns == 21:
        mocap_cov(Lk, sig2, rho, cov)
        P[15:21, 15:21, :] = cov


@kernel
def step_lever(Lk, Lprev, dL, a, hk, ns, t_corr):  # pragma: no cover  (compiled)
    """With AR(1) states, their transition ``a [[I, 0], [dL, I]]`` over a step (``Lk`` the
    lever arm at its end sample, ``Lprev`` at its start)."""
    for v in range(LANES):
        a[v] = np.exp(-hk[v] / t_corr) if ns == 21 else 0.0
    for i in range(3):
        for t in range(3):
            for v in range(LANES):
                dL[i, t, v] = Lprev[i, t, v] - Lk[i, t, v]


@kernel
def propagate(Y, X, P, p, ns, hk, Fc, Fo, dwfL, dg, gcols, a, dL, Lk, par, tmp, cov,
              qm):  # pragma: no cover  (compiled)
    """One step: the sensitivities ``S`` (rows 0:9 of ``Y``) through the current transition
    ``Fc`` with the parameters' inputs (``-d(w, f)/dtheta`` as bias rows, gravity directly),
    the filter mean and covariance through the whitening's transition ``Fo``."""
    if p > 0:
        for i in range(6):
            for c in range(p):
                for v in range(LANES):
                    Y[9 + i, c, v] = -dwfL[i, c, v]
        phi_rows(Y, p, Fc, hk, 15, a, dL, tmp)
        for g in range(gcols.shape[0]):
            col = gcols[g]
            for i in range(3):
                for v in range(LANES):
                    Y[3 + i, col, v] += 0.5 * hk[v] * hk[v] * dg[i, g]
                    Y[6 + i, col, v] += hk[v] * dg[i, g]
    phi_rows(X, p + 1, Fo, hk, ns, a, dL, tmp)
    predict_cov(P, ns, Fo, hk, a, dL, Lk, par, tmp, cov, qm)


@kernel
def residual_rows(N, Y, p, rs, ts, rL, JL, PL, RL):  # pragma: no cover  (compiled)
    """A sample's ``[J | r]`` rows: ``J`` is the direct part minus the nominal's
    sensitivity."""
    for i in range(3):
        for c in range(p):
            for v in range(LANES):
                N[i, c, v] = -(PL[i, 0, v] * Y[0, c, v] + PL[i, 1, v] * Y[1, c, v]
                               + PL[i, 2, v] * Y[2, c, v])
                N[3 + i, c, v] = -Y[3 + i, c, v]
        if p > 0:
            for j in range(3):
                for v in range(LANES):
                    N[i, rs + j, v] += JL[i, j, v]
                    N[3 + i, ts + j, v] += RL[i, j, v]
    for i in range(6):
        for v in range(LANES):
            N[i, p, v] = rL[i, v]


@kernel
def innovate(N, X, P, PHt, S, p, ns):  # pragma: no cover  (compiled)
    """``N -= H X`` (the rows' innovations); ``PHt = P H^T``; ``S = H P H^T`` (H picks the
    error state's attitude and position and adds the AR(1) mocap states)."""
    for i in range(6):
        for c in range(p + 1):
            for v in range(LANES):
                N[i, c, v] -= X[i, c, v] + (X[15 + i, c, v] if ns == 21 else 0.0)
    for i in range(ns):
        for j in range(6):
            for v in range(LANES):
                PHt[i, j, v] = P[i, j, v] + (P[i, 15 + j, v] if ns == 21 else 0.0)
    for i in range(6):
        for j in range(6):
            for v in range(LANES):
                S[i, j, v] = PHt[i, j, v] + (PHt[15 + i, j, v] if ns == 21 else 0.0)


@kernel
def whiten(Nw, N, HPHt, cov, owt, ok, Sk, Lc, dinv, ld, p):  # pragma: no cover  (compiled)
    """``Nw = Lc^-1 N`` with ``Lc`` the Cholesky factor of the innovation covariance (the
    white mocap noise inflated by the robust weight); zero in lanes without a sample."""
    for i in range(6):
        for j in range(6):
            for v in range(LANES):
                Sk[i, j, v] = HPHt[i, j, v] + cov[i, j, v] / owt[v]
    cholesky6(Sk, Lc, dinv, ld)
    forward(Lc, dinv, N, p + 1, Nw)
    for i in range(6):
        for c in range(p + 1):
            for v in range(LANES):
                Nw[i, c, v] = Nw[i, c, v] if ok[v] > 0.0 else 0.0


@kernel
def accumulate(Nw, p, blk, G, Sc, ld, ok, ldsum):  # pragma: no cover  (compiled)
    """A sample's whitened rows into the Gram matrices (upper triangles), the scores of its
    block and the log dets."""
    for t in range(6):
        for a in range(p + 1):
            for b in range(a, p + 1):
                for v in range(LANES):
                    G[a, b, v] += Nw[t, a, v] * Nw[t, b, v]
    if Sc.shape[0] > 0:
        for c in range(p):
            for t in range(6):
                for v in range(LANES):
                    Sc[blk, c, v] += Nw[t, c, v] * Nw[t, p, v]
    for v in range(LANES):
        ldsum[v] += ld[v] if ok[v] > 0.0 else 0.0


@kernel
def robust_norm(N, HPHt, cov, wt, ok, col, d, p):  # pragma: no cover  (compiled)
    """Where a sample is down-weighted: the norm of its innovation whitened with the
    unweighted noise (the robust weight's own test) into ``d``."""
    Sk, Lc = np.empty((6, 6, LANES)), np.empty((6, 6, LANES))
    dinv, ld = np.empty((6, LANES)), np.empty(LANES)
    for i in range(6):
        for j in range(6):
            for v in range(LANES):
                Sk[i, j, v] = HPHt[i, j, v] + cov[i, j, v]
    cholesky6(Sk, Lc, dinv, ld)
    forward(Lc, dinv, N[:, p:], 1, col)
    for v in range(LANES):
        if ok[v] > 0.0 and wt[v] < 1.0:
            q = 0.0
            for i in range(6):
                q += col[i, 0, v] * col[i, 0, v]
            d[v] = np.sqrt(q)


@kernel
def measure(k, lane, n_real, ok, wt, owt, Y, X, P, N, Nw, PHt, U, HPHt, Sk, Lc, dinv, ld, cov,
            white, Lk, col, dn, p, ns, rs, ts, par, rL, JL, PL, RL, blk, G, Sc, ldsum, innov,
            e_white, d_raw, raw_J, whitened):  # pragma: no cover  (compiled)
    """Sample ``k`` of every lane: residual rows, whitening, sums, filter update."""
    residual_rows(N, Y, p, rs, ts, rL, JL, PL, RL)
    if raw_J.shape[0] > 0:
        for v in range(n_real):
            if ok[v] > 0.0:
                raw_J[lane[v], k, :, :] = N[:, :p, v]
    innovate(N, X, P, PHt, HPHt, p, ns)
    mocap_cov(Lk, par[SIG2:SIG2 + 6], white, cov)
    whiten(Nw, N, HPHt, cov, owt, ok, Sk, Lc, dinv, ld, p)
    accumulate(Nw, p, blk, G, Sc, ld, ok, ldsum)
    for v in range(LANES):
        q = 0.0
        for i in range(6):
            q += Nw[i, p, v] * Nw[i, p, v]
        dn[v] = np.sqrt(q)
    weighted = False
    for v in range(n_real):
        weighted = weighted or (ok[v] > 0.0 and wt[v] < 1.0)
    if weighted:
        robust_norm(N, HPHt, cov, wt, ok, col, dn, p)
    for v in range(n_real):
        if ok[v] > 0.0:
            w = lane[v]
            d_raw[w, k] = dn[v]
            for i in range(6):
                innov[w, k, i] = N[i, p, v]
                e_white[w, k, i] = Nw[i, p, v]
            if whitened.shape[0] > 0:
                whitened[w, k, :, :] = Nw[:, :, v]
    gain_update(X, P, Nw, PHt, Lc, dinv, U, ok, ns, p)


@kernel
def filter_windows(h, mask, wts, inc, Rbar, op_inc, op_Rbar, op_wts, frozen, dwf, dg, gcols,
                   r, Jinv, Pm_rot, R_WM, M_op, par, rs, ts, blocks, gram, innov, e_white,
                   d_raw, logdet, scores, raw_J, whitened):  # pragma: no cover  (compiled)
    """The filter pass over every window (outputs zeroed by the caller). With ``frozen`` the
    filter (mean transition, covariance, gains, whitening) runs on the whitening's own
    increments ``op_inc``, ``op_Rbar``, noise ``par``/``M_op`` and weights ``op_wts`` while the
    sensitivities follow the current ones, so the cost is a fixed weighted least squares."""
    W, m = h.shape
    p = dwf.shape[3]
    ns = 21 if (par[RHO] > 0.0 and par[T_CORR] > 0.0) else 15
    V = LANES
    Y, X, P = np.zeros((15, max(p, 1), V)), np.zeros((ns, p + 1, V)), np.zeros((ns, ns, V))
    PHt, U = np.zeros((ns, 6, V)), np.zeros((ns, 6, V))
    N, Nw, tmp = np.zeros((6, p + 1, V)), np.zeros((6, p + 1, V)), np.zeros((9, max(p + 1, ns), V))
    Fc, Fo = np.zeros((8, 3, 3, V)), np.zeros((8, 3, 3, V))
    HPHt, Sk, Lc, cov = (np.zeros((6, 6, V)), np.zeros((6, 6, V)), np.zeros((6, 6, V)),
                         np.zeros((6, 6, V)))
    dinv, col, rL = np.zeros((6, V)), np.zeros((6, 1, V)), np.zeros((6, V))
    Lk, Lprev, dL = np.zeros((3, 3, V)), np.zeros((3, 3, V)), np.zeros((3, 3, V))
    JL, PL, RL = np.zeros((3, 3, V)), np.zeros((3, 3, V)), np.zeros((3, 3, V))
    incL, RkL, oincL, oRkL = (np.zeros((N_INC, V)), np.zeros((3, 3, V)), np.zeros((N_INC, V)),
                              np.zeros((3, 3, V)))
    dwfL, G = np.zeros((6, max(p, 1), V)), np.zeros((p + 1, p + 1, V))
    Sc = np.zeros((scores.shape[1], p, V))
    hk, a, ok, wt, owt, ld, qm, dn, ldsum = (np.zeros(V), np.zeros(V), np.zeros(V), np.zeros(V),
                                            np.zeros(V), np.zeros(V), np.zeros(V), np.zeros(V),
                                            np.zeros(V))
    white = np.full(V, 1.0 - par[RHO] if ns == 21 else 1.0)
    rho = np.full(V, par[RHO])
    lane = np.zeros(V, np.int64)
    for g in range((W + V - 1) // V):
        n_real = lanes_of(W, g, lane)
        last = 0
        for v in range(n_real):
            for k in range(m + 1):
                if mask[lane[v], k]:
                    last = max(last, k)
        G[:, :, :] = 0.0
        Sc[:, :, :] = 0.0
        ldsum[:] = 0.0
        for k in range(last + 1):
            any_ok = gather_sample(k, lane, n_real, mask, wts, op_wts, r, Jinv, Pm_rot, R_WM,
                                   ok, wt, owt, rL, JL, PL, RL)
            if k == 0:
                start_group(Y, X, P, p, ns, rs, ts, RL, M_op, Lk, par[SIG2:SIG2 + 6], rho, cov)
            else:
                gather_step(k - 1, lane, h, inc, Rbar, dwf, hk, incL, RkL, dwfL)
                transition_blocks(incL, RkL, Fc)
                if frozen:
                    gather_op(k - 1, lane, op_inc, op_Rbar, oincL, oRkL)
                    transition_blocks(oincL, oRkL, Fo)
                else:
                    Fo[:, :, :, :] = Fc
                Lprev[:, :, :] = Lk
                lever(RL, M_op, Lk)
                step_lever(Lk, Lprev, dL, a, hk, ns, par[T_CORR])
                propagate(Y, X, P, p, ns, hk, Fc, Fo, dwfL, dg, gcols, a, dL, Lk, par, tmp, cov,
                          qm)
            if any_ok:
                measure(k, lane, n_real, ok, wt, owt, Y, X, P, N, Nw, PHt, U, HPHt, Sk, Lc, dinv,
                        ld, cov, white, Lk, col, dn, p, ns, rs, ts, par, rL, JL, PL, RL,
                        blocks[k], G, Sc, ldsum, innov, e_white, d_raw, raw_J, whitened)
        for v in range(n_real):
            w = lane[v]
            logdet[w] = ldsum[v]
            for i in range(p + 1):
                for j in range(p + 1):
                    gram[w, i, j] = G[min(i, j), max(i, j), v]
            if scores.shape[1] > 0:
                scores[w, :, :] = Sc[:, :, v]


@kernel
def state_space(inc, Rbar, h, R_WM, M, par, F, q_diag, q_pv, Rn, Fm, Qm,
                Pm0):  # pragma: no cover  (compiled)
    """The window filter's state-space model written out (for checks against a dense
    likelihood): transitions, process noise, white mocap noise and the AR(1) states' model."""
    W, m = h.shape
    ns = 21 if (par[RHO] > 0.0 and par[T_CORR] > 0.0) else 15
    V = LANES
    Fb, cov, Lk, Lprev, dL = (np.zeros((8, 3, 3, V)), np.zeros((6, 6, V)), np.zeros((3, 3, V)),
                              np.zeros((3, 3, V)), np.zeros((3, 3, V)))
    incL, RkL, RL, hk, a = (np.zeros((N_INC, V)), np.zeros((3, 3, V)), np.zeros((3, 3, V)),
                            np.zeros(V), np.zeros(V))
    white, rho, qm = (np.full(V, 1.0 - par[RHO] if ns == 21 else 1.0), np.full(V, par[RHO]),
                      np.zeros(V))
    lane = np.zeros(V, np.int64)
    for g in range((W + V - 1) // V):
        n_real = lanes_of(W, g, lane)
        for k in range(m + 1):
            for v in range(V):
                RL[:, :, v] = R_WM[lane[v], k]
            Lprev[:, :, :] = Lk
            lever(RL, M, Lk)
            mocap_cov(Lk, par[SIG2:SIG2 + 6], white, cov)
            for v in range(n_real):
                Rn[lane[v], k] = cov[:, :, v]
            if k == 0:
                if ns == 21:
                    mocap_cov(Lk, par[SIG2:SIG2 + 6], rho, cov)
                    for v in range(n_real):
                        Pm0[lane[v]] = cov[:, :, v]
                continue
            gather_op(k - 1, lane, inc, Rbar, incL, RkL)
            for v in range(V):
                hk[v] = h[lane[v], k - 1]
            transition_blocks(incL, RkL, Fb)
            step_lever(Lk, Lprev, dL, a, hk, ns, par[T_CORR])
            for v in range(V):
                qm[v] = par[RHO] * (1.0 - a[v] * a[v])
            mocap_cov(Lk, par[SIG2:SIG2 + 6], qm, cov)
            for v in range(n_real):
                write_step(lane[v], k - 1, v, hk[v], a[v], Fb, dL, cov, ns, par, F, q_diag, q_pv,
                           Fm, Qm)


@kernel
def write_step(w, j, v, h, a, Fb, dL, cov, ns, par, F, q_diag, q_pv, Fm,
               Qm):  # pragma: no cover  (compiled)
    """Step ``j`` of window ``w`` (lane ``v``) of :func:`state_space`."""
    for i in range(15):
        F[w, j, i, i] = 1.0
    for i in range(3):
        F[w, j, 3 + i, 6 + i] = h
        for b, (r0, c0) in enumerate(((0, 0), (0, 9), (3, 0), (3, 9), (3, 12), (6, 0), (6, 9),
                                      (6, 12))):
            for t in range(3):
                F[w, j, r0 + i, c0 + t] = Fb[b, i, t, v]
        q_diag[w, j, i] = par[Q_GYRO] * h
        q_diag[w, j, 3 + i] = par[Q_ACCEL] * h ** 3 / 3.0
        q_diag[w, j, 6 + i] = par[Q_ACCEL] * h
        q_diag[w, j, 9 + i] = par[Q_GYRO_WALK] * h
        q_diag[w, j, 12 + i] = par[Q_ACCEL_WALK] * h
    q_pv[w, j] = par[Q_ACCEL] * h ** 2 / 2.0
    if ns == 21:
        for i in range(6):
            Fm[w, j, i, i] = a
        for i in range(3):
            for t in range(3):
                Fm[w, j, 3 + i, t] = a * dL[i, t, v]
        Qm[w, j] = cov[:, :, v]
