"""The window filter, compiled: one pass over the samples of every window (see
:mod:`mocap_calib.core.position.engine` for the model and :mod:`.kalman` for the calls).

Per window and sample the pass propagates the nominal trajectory's sensitivities ``S`` and the
filter state (mean ``X`` for every column of ``[J | r]``, covariance ``P``) through the step's
error-state transition, whitens the sample's residual rows with the Cholesky factor of the
innovation covariance and sums the Gram matrix, the scores and the likelihood's parts. The
transition is built from the step's increments (its zero and identity blocks cost nothing), the
process noise from the densities and the mocap noise from the lever arm, so nothing of size
(windows x samples x states x states) is ever stored.

Layouts: ``inc`` (W, m, 51) is a step's packed increments (dR, dv, dp, A, C, B, D, see
:func:`~mocap_calib.core.model.preint.integrate_pieces`); ``par`` holds the noise: gyro and accel
noise densities squared, their random walks squared, the correlated fraction and time constant of
the mocap noise (AR(1) states when both are positive) and the six white mocap variances
(attitude in the IMU frame, position in the world frame), and the accelerometer's per-axis
factors.
"""

from __future__ import annotations

import numpy as np

from mocap_calib.core.jit import kernel

#: Index of the noise parameters in ``par``: the densities squared, the mocap noise's AR(1)
#: fraction and time constant, its six white variances, and the accelerometer's white-noise
#: variance factors per IMU axis (all ones: isotropic).
Q_GYRO, Q_ACCEL, Q_GYRO_WALK, Q_ACCEL_WALK, RHO, T_CORR, SIG2, ACCEL_AXES = (
    0, 1, 2, 3, 4, 5, 6, 12)
N_PAR = 15
#: Diffuse prior of a window's start state: attitude (rad), position (m), velocity (m/s).
DIFFUSE = (1.0, 1.0, 0.5)

# ruff: noqa: N803, N806  (matrix names)


@kernel(inline=True)
def transition_blocks(inc, w, s, Rk, Fb):  # pragma: no cover  (compiled)
    """The non-trivial 3x3 blocks of the error-state transition of step ``s`` of window ``w``
    (increments ``inc[w, s]``, read in place: a view costs two atomic reference counts), into
    ``Fb`` (8, 3, 3):
    F00 = dR^T, F03 = -dR^T A, F10 = -Rk [dp]x, F13 = Rk D, F14 = -Rk C, F20 = -Rk [dv]x,
    F23 = Rk B, F24 = -Rk A (block rows: attitude, position, velocity; columns also gyro and
    accel bias). The others: identity on the diagonal, ``h I`` at position/velocity."""
    for i in range(3):
        for j in range(3):
            Fb[0, i, j] = inc[w, s, 3 * j + i]
    for i in range(3):
        for j in range(3):
            f03 = 0.0
            f13 = f14 = f23 = f24 = 0.0
            for t in range(3):
                f03 -= Fb[0, i, t] * inc[w, s, 15 + 3 * t + j]
                f13 += Rk[i, t] * inc[w, s, 42 + 3 * t + j]
                f14 -= Rk[i, t] * inc[w, s, 24 + 3 * t + j]
                f23 += Rk[i, t] * inc[w, s, 33 + 3 * t + j]
                f24 -= Rk[i, t] * inc[w, s, 15 + 3 * t + j]
            Fb[1, i, j] = f03
            Fb[3, i, j] = f13
            Fb[4, i, j] = f14
            Fb[6, i, j] = f23
            Fb[7, i, j] = f24
        # -Rk [x]x: column j of [x]x is e_j x x.
        for k, base in ((2, 12), (5, 9)):
            x0, x1, x2 = inc[w, s, base], inc[w, s, base + 1], inc[w, s, base + 2]
            Fb[k, i, 0] = -(Rk[i, 1] * x2 - Rk[i, 2] * x1)
            Fb[k, i, 1] = -(-Rk[i, 0] * x2 + Rk[i, 2] * x0)
            Fb[k, i, 2] = -(Rk[i, 0] * x1 - Rk[i, 1] * x0)


@kernel(inline=True)
def copy33(A, w, k, out):  # pragma: no cover  (compiled)
    """``out`` (3, 3) = ``A[w, k]`` element by element (no view: see
    :func:`transition_blocks`)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[w, k, i, j]


@kernel(inline=True)
def phi_rows(Mx, nc, Fb, hk, ns, ni, a, tmp):  # pragma: no cover  (compiled)
    """``Mx[:, :nc] <- Phi Mx[:, :nc]`` in place: the error-state rows through the transition
    blocks ``Fb``; with AR(1) mocap states (ns 21) those decay by ``a``; the ``ni`` bias
    integral rows after them (see :func:`filter_windows`) add the step times the bias rows."""
    for i in range(3):
        for c in range(nc):
            tmp[i, c] = 0.0
            tmp[3 + i, c] = Mx[3 + i, c] + hk * Mx[6 + i, c]
            tmp[6 + i, c] = Mx[6 + i, c]
        for t in range(3):
            f00, f03 = Fb[0, i, t], Fb[1, i, t]
            f10, f13, f14 = Fb[2, i, t], Fb[3, i, t], Fb[4, i, t]
            f20, f23, f24 = Fb[5, i, t], Fb[6, i, t], Fb[7, i, t]
            for c in range(nc):
                x, bg, ba = Mx[t, c], Mx[9 + t, c], Mx[12 + t, c]
                tmp[i, c] += f00 * x + f03 * bg
                tmp[3 + i, c] += f10 * x + f13 * bg + f14 * ba
                tmp[6 + i, c] += f20 * x + f23 * bg + f24 * ba
    for i in range(9):
        for c in range(nc):
            Mx[i, c] = tmp[i, c]
    if ns == 21:
        for i in range(15, 21):
            for c in range(nc):
                Mx[i, c] *= a
    for i in range(ni):  # the bias rows are unchanged by the step
        for c in range(nc):
            Mx[ns + i, c] += hk * Mx[9 + i, c]


@kernel(inline=True)
def mocap_cov(par, scale, out):  # pragma: no cover  (compiled)
    """``out`` (6, 6) = scale times the covariance of a residual's mocap noise: attitude
    variances ``par[SIG2:SIG2 + 3]`` (IMU frame), position ``par[SIG2 + 3:SIG2 + 6]`` (world
    frame), independent (the lever arm acts through the filter's attitude, not through the
    measured one)."""
    for i in range(6):
        for j in range(6):
            out[i, j] = scale * par[SIG2 + i] if i == j else 0.0


@kernel(inline=True)
def lever(R, M, L):  # pragma: no cover  (compiled)
    """``L = R M`` (3x3) with ``R`` the nominal IMU attitude and ``M = [R_MI^T p_MI]x``: the
    position residual's rows on the attitude error (the marker origin sits at ``-R_MI^T p_MI``
    in the IMU frame)."""
    for i in range(3):
        for j in range(3):
            L[i, j] = R[i, 0] * M[0, j] + R[i, 1] * M[1, j] + R[i, 2] * M[2, j]


@kernel(inline=True)
def accel_noise(par, R, Qa):  # pragma: no cover  (compiled)
    """``Qa`` (3, 3) = the accelerometer's white-noise variance in the world frame at the
    nominal attitude ``R``: ``R diag(q) R^T`` with the per-axis factors; returns False when
    they are all one (``q I``, whatever ``R``)."""
    f0, f1, f2 = par[ACCEL_AXES], par[ACCEL_AXES + 1], par[ACCEL_AXES + 2]
    if f0 == 1.0 and f1 == 1.0 and f2 == 1.0:
        return False
    for i in range(3):
        for j in range(3):
            Qa[i, j] = par[Q_ACCEL] * (R[i, 0] * f0 * R[j, 0] + R[i, 1] * f1 * R[j, 1]
                                       + R[i, 2] * f2 * R[j, 2])
    return True


@kernel(inline=True)
def predict_cov(P, ns, ni, Fb, hk, a, par, tmp, cov, R):  # pragma: no cover  (compiled)
    """Filter covariance through a step: ``Phi P Phi^T`` plus the process noise (the
    accelerometer's at the step's start attitude ``R``) and the AR(1) states' innovation,
    ``rho (1 - a^2)`` of the mocap noise at the step's end sample."""
    nt = ns + ni
    phi_rows(P, nt, Fb, hk, ns, ni, a, tmp)
    for i in range(nt):
        for j in range(i + 1, nt):
            P[i, j], P[j, i] = P[j, i], P[i, j]
    phi_rows(P, nt, Fb, hk, ns, ni, a, tmp)
    for i in range(3):
        P[i, i] += par[Q_GYRO] * hk
        P[9 + i, 9 + i] += par[Q_GYRO_WALK] * hk
        P[12 + i, 12 + i] += par[Q_ACCEL_WALK] * hk
    # The accelerometer's noise: off the diagonal only when it differs per IMU axis.
    n = 3 if accel_noise(par, R, cov) else 1
    for i in range(3):
        for j in range(3) if n == 3 else range(i, i + 1):
            q = cov[i, j] if n == 3 else par[Q_ACCEL]
            P[3 + i, 3 + j] += q * hk * hk * hk / 3.0
            P[6 + i, 6 + j] += q * hk
            P[3 + i, 6 + j] += q * hk * hk / 2.0
            P[6 + i, 3 + j] += q * hk * hk / 2.0
    if ns == 21:
        mocap_cov(par, par[RHO] * (1.0 - a * a), cov)
        for i in range(6):
            for j in range(6):
                P[15 + i, 15 + j] += cov[i, j]


@kernel(inline=True)
def cholesky6(A, Lc):  # pragma: no cover  (compiled)
    """Lower Cholesky factor of the 6x6 ``A``; returns log det A."""
    det = 1.0
    for j in range(6):
        s = A[j, j]
        for t in range(j):
            s -= Lc[j, t] * Lc[j, t]
        d = np.sqrt(s)
        Lc[j, j] = d
        det *= s  # the product of the pivots (far from the range's ends at these scales)
        for i in range(j + 1, 6):
            s = A[i, j]
            for t in range(j):
                s -= Lc[i, t] * Lc[j, t]
            Lc[i, j] = s / d
        for i in range(j):
            Lc[i, j] = 0.0
    return np.log(det)


@kernel(inline=True)
def forward(Lc, B, nc, out):  # pragma: no cover  (compiled)
    """``out[:, :nc] = Lc^-1 B[:, :nc]`` (forward substitution, 6 rows)."""
    for i in range(6):
        d = 1.0 / Lc[i, i]
        for c in range(nc):
            s = B[i, c]
            for t in range(i):
                s -= Lc[i, t] * out[t, c]
            out[i, c] = s * d


@kernel(inline=True)
def propagate(Y, X, P, p, ns, ni, hk, Fc, Fo, dwf, w, s, dg, gcols, a, par, tmp, cov,
              R):  # pragma: no cover  (compiled)
    """One step: the sensitivities ``S`` (rows 0:9 of ``Y``) through the current transition
    ``Fc`` with the parameters' inputs (``-d(w, f)/dtheta`` as bias rows, gravity directly),
    the filter mean and covariance through the whitening's transition ``Fo`` (``R``: its
    attitude at the step's start); ``dwf[w, s]``: step ``s`` of window ``w``."""
    if p > 0:
        for i in range(6):
            for c in range(p):
                Y[9 + i, c] = -dwf[w, s, i, c]
        phi_rows(Y, p, Fc, hk, min(ns, 15), 0 * ni, 0.0, tmp)  # (no literal: one compile)
        for g in range(gcols.shape[0]):
            col = gcols[g]
            for i in range(3):
                Y[3 + i, col] += 0.5 * hk * hk * dg[i, g]
                Y[6 + i, col] += hk * dg[i, g]
    phi_rows(X, p + 1, Fo, hk, ns, ni, a, tmp)
    predict_cov(P, ns, ni, Fo, hk, a, par, tmp, cov, R)


@kernel(inline=True)
def residual_rows(N, Y, X, p, ns, rs, ts, w, k, r, Jinv, Pm_rot, Jp,
                  Hq):  # pragma: no cover  (compiled)
    """A sample's ``[J | r]`` rows (``J``: the direct part minus the nominal's sensitivity;
    the position rows see the nominal attitude through ``Hq = R_bar [R_MI^T p_MI]x``); the
    direct parts are sample ``k`` of window ``w``'s."""
    for i in range(3):
        q0, q1, q2 = Hq[w, k, i, 0], Hq[w, k, i, 1], Hq[w, k, i, 2]
        m0, m1, m2 = Pm_rot[w, k, i, 0], Pm_rot[w, k, i, 1], Pm_rot[w, k, i, 2]
        for c in range(p):
            N[i, c] = -(m0 * Y[0, c] + m1 * Y[1, c] + m2 * Y[2, c])
            N[3 + i, c] = -Y[3 + i, c] - (q0 * Y[0, c] + q1 * Y[1, c] + q2 * Y[2, c])
        if p > 0:
            for j in range(3):
                N[i, rs + j] += Jinv[w, k, i, j]
                N[3 + i, rs + j] += Hq[w, k, i, j]
                N[3 + i, ts + j] += Jp[w, k, i, j]
    for i in range(6):
        N[i, p] = r[w, k, i]


@kernel(inline=True)
def innovate(N, X, P, PHt, S, ns, nt, p, Lk):  # pragma: no cover  (compiled)
    """``N -= H X``; ``PHt = P H^T`` (all ``nt`` states); ``S = H P H^T``. ``H`` picks the
    error state's attitude for the attitude rows and position plus ``Lk`` times attitude for the
    position rows, and adds the AR(1) mocap states."""
    for c in range(p + 1):
        for i in range(3):
            N[i, c] -= X[i, c] + (X[15 + i, c] if ns == 21 else 0.0)
            N[3 + i, c] -= (X[3 + i, c] + Lk[i, 0] * X[0, c] + Lk[i, 1] * X[1, c]
                            + Lk[i, 2] * X[2, c] + (X[18 + i, c] if ns == 21 else 0.0))
    for i in range(nt):
        for j in range(3):
            PHt[i, j] = P[i, j] + (P[i, 15 + j] if ns == 21 else 0.0)
            PHt[i, 3 + j] = (P[i, 3 + j] + P[i, 0] * Lk[j, 0] + P[i, 1] * Lk[j, 1]
                             + P[i, 2] * Lk[j, 2] + (P[i, 18 + j] if ns == 21 else 0.0))
    for j in range(6):
        for i in range(3):
            S[i, j] = PHt[i, j] + (PHt[15 + i, j] if ns == 21 else 0.0)
            S[3 + i, j] = (PHt[3 + i, j] + Lk[i, 0] * PHt[0, j] + Lk[i, 1] * PHt[1, j]
                           + Lk[i, 2] * PHt[2, j] + (PHt[18 + i, j] if ns == 21 else 0.0))


@kernel(inline=True)
def gain_update(X, P, Nw, PHt, Lc, U, ns, p):  # pragma: no cover  (compiled)
    """Kalman update of mean and covariance in square-root form: with ``U = P H^T Lc^-T``
    (``Lc`` the innovation covariance's Cholesky factor, ``Nw = Lc^-1 N`` the whitened rows),
    ``X += U Nw`` and ``P -= U U^T`` (the gain ``K = U Lc^-1``)."""
    for i in range(ns):
        for t in range(6):
            s = PHt[i, t]
            for v in range(t):
                s -= U[i, v] * Lc[t, v]
            U[i, t] = s / Lc[t, t]
    for i in range(ns):
        for c in range(p + 1):
            s = 0.0
            for t in range(6):
                s += U[i, t] * Nw[t, c]
            X[i, c] += s
        for j in range(i, ns):
            s = 0.0
            for t in range(6):
                s += U[i, t] * U[j, t]
            P[i, j] -= s
            if j > i:
                P[j, i] = P[i, j]


@kernel(inline=True)
def accumulate(w, k, Nw, p, blocks, G, scores, e_white, whitened):  # pragma: no cover
    """A sample's whitened rows into the window's Gram matrix ``G[w]`` (upper triangle) and
    scores."""
    for i in range(6):
        e_white[w, k, i] = Nw[i, p]
    for a in range(p + 1):  # row a's six factors held, the b loop runs along the rows
        n0, n1, n2, n3, n4, n5 = Nw[0, a], Nw[1, a], Nw[2, a], Nw[3, a], Nw[4, a], Nw[5, a]
        for b in range(a, p + 1):
            G[w, a, b] += (n0 * Nw[0, b] + n1 * Nw[1, b] + n2 * Nw[2, b] + n3 * Nw[3, b]
                           + n4 * Nw[4, b] + n5 * Nw[5, b])
    if scores.shape[1] > 0:
        blk = blocks[k]
        for c in range(p):
            s = 0.0
            for t in range(6):
                s += Nw[t, c] * Nw[t, p]
            scores[w, blk, c] += s
    if whitened.shape[0] > 0:
        for t in range(6):
            for c in range(p + 1):
                whitened[w, k, t, c] = Nw[t, c]


@kernel(inline=True)
def start_window(Y, X, P, p, ns, rs, ts, R0, Ratt, M_op, Lk, par, cov):  # pragma: no cover
    """A window's start: the diffuse prior, the AR(1) states' stationary covariance, the
    sensitivities of the start pose to ``R_MI`` and ``p_MI`` (``R0``: the first mocap
    attitude), the position rows' attitude block at the nominal attitude ``Ratt``."""
    Y[:, :] = 0.0
    X[:, :] = 0.0
    P[:, :] = 0.0
    for i in range(3):
        for j in range(3):
            P[3 * j + i, 3 * j + i] = DIFFUSE[j] ** 2
        if p > 0:
            Y[i, rs + i] = 1.0
            for j in range(3):
                Y[3 + i, ts + j] = R0[i, j]
    lever(Ratt, M_op, Lk)
    if ns == 21:
        mocap_cov(par, par[RHO], cov)
        P[15:21, 15:21] = cov


@kernel(inline=True)
def step_lever(R, M_op, Lk, hk, ns, par):  # pragma: no cover  (compiled)
    """The position rows' attitude block at the step's end sample (nominal attitude ``R``)
    into ``Lk``; with AR(1) states their decay over the step: returns ``a``."""
    lever(R, M_op, Lk)
    if ns != 21:
        return 0.0
    return np.exp(-hk / par[T_CORR])


@kernel(inline=True)
def chain(R, inc, w, s, Rnext):  # pragma: no cover  (compiled)
    """``R <- R dR`` (the next nominal attitude; ``dR`` of step ``s`` of window ``w``), with
    ``compose``'s arithmetic."""
    for i in range(3):
        for j in range(3):
            Rnext[i, j] = (R[i, 0] * inc[w, s, j] + R[i, 1] * inc[w, s, 3 + j]
                           + R[i, 2] * inc[w, s, 6 + j])
    R[:, :] = Rnext


@kernel(inline=True)
def whiten_sample(w, k, Y, X, P, N, Nw, PHt, HPHt, Sk, Lc, cov, Lk, p, ns, ni, rs, ts, white,
                  op_wt, par, r, Jinv, Pm_rot, Jp, Hq, raw_J):  # pragma: no cover  (compiled)
    """Sample ``k`` of window ``w``: its residual rows ``N`` less the filter's prediction,
    their innovation covariance's Cholesky factor ``Lc`` and the whitened rows ``Nw``; returns
    the log det of the innovation covariance."""
    residual_rows(N, Y, X, p, ns, rs, ts, w, k, r, Jinv, Pm_rot, Jp, Hq)
    if raw_J.shape[0] > 0:
        for i in range(6):
            for c in range(p):
                raw_J[w, k, i, c] = N[i, c]
    innovate(N, X, P, PHt, HPHt, ns, ns + ni, p, Lk)
    mocap_cov(par, white, cov)
    for i in range(6):
        for j in range(6):
            Sk[i, j] = HPHt[i, j] + cov[i, j] / op_wt
    ld = cholesky6(Sk, Lc)
    forward(Lc, N, p + 1, Nw)
    return ld


@kernel(inline=True)
def use_sample(w, k, X, P, N, Nw, PHt, K, HPHt, Sk, Lc, Li, cov, p, nt, wt, blocks, gram, innov,
               e_white, d_raw, scores, whitened):  # pragma: no cover  (compiled)
    """Sample ``k`` of window ``w`` after :func:`whiten_sample`: its whitened rows into the
    sums and statistics, then the filter's update."""
    accumulate(w, k, Nw, p, blocks, gram, scores, e_white, whitened)
    q = 0.0
    for i in range(6):
        innov[w, k, i] = N[i, p]
        q += Nw[i, p] * Nw[i, p]
    d_raw[w, k] = np.sqrt(q)
    if wt < 1.0:  # the robust weight's own test: the innovation against the unweighted noise
        for i in range(6):
            for j in range(6):
                Sk[i, j] = HPHt[i, j] + cov[i, j]
        cholesky6(Sk, Li)
        for i in range(6):  # the innovation column into a C array: forward compiles once
            cov[i, 0] = N[i, p]
        forward(Li, cov, N.shape[1] - p, Sk)
        q = 0.0
        for i in range(6):
            q += Sk[i, 0] * Sk[i, 0]
        d_raw[w, k] = np.sqrt(q)
    gain_update(X, P, Nw, PHt, Lc, K, nt, p)


@kernel
def filter_windows(h, mask, wts, inc, Rbar, op_inc, op_R0, op_wts, frozen, dwf, dg, gcols,
                   r, Jinv, Pm_rot, Jp, Hq, R_WM0, M_op, par, rs, ts, blocks, gram, innov,
                   e_white, d_raw, logdet, scores, raw_J, whitened, term_X, term_P, int_X,
                   int_P):  # pragma: no cover
    """The filter pass over every window (outputs zeroed by the caller). With ``frozen`` the
    filter (mean transition, covariance, gains, whitening) runs on the whitening's own
    increments ``op_inc`` (its attitudes chained from ``op_R0`` as ``compose`` does), noise
    ``par``/``M_op`` and weights ``op_wts`` while the sensitivities follow the current ones, so
    the cost is a fixed weighted least squares.

    With ``int_X`` (W, 6, p+1) non-empty the state also carries the time integral of the bias
    error over the window (6 more states after the others, zero at the start): its mean per
    column goes to ``int_X`` and, into ``int_P`` (W, 6, 12), its covariance and its covariance
    with the end bias."""
    W, m = h.shape
    p = dwf.shape[3]
    ns = 21 if (par[RHO] > 0.0 and par[T_CORR] > 0.0) else 15
    ni = 6 if int_X.shape[0] > 0 else 0
    nt = ns + ni
    white = 1.0 - par[RHO] if ns == 21 else 1.0
    Y, X = np.zeros((15, max(p, 1))), np.zeros((nt, p + 1))
    P, PHt, K = np.zeros((nt, nt)), np.zeros((nt, 6)), np.zeros((nt, 6))
    N, Nw = np.zeros((6, p + 1)), np.zeros((6, p + 1))
    tmp = np.zeros((9, max(p + 1, nt)))
    Fc, Fo = np.zeros((8, 3, 3)), np.zeros((8, 3, 3))
    HPHt, Sk, Lc, Li, cov = (np.zeros((6, 6)), np.zeros((6, 6)), np.zeros((6, 6)),
                             np.zeros((6, 6)), np.zeros((6, 6)))
    Lk = np.zeros((3, 3))
    Rop, Rnext, Rstart, Rk = (np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)),
                              np.zeros((3, 3)))
    for w in range(W):
        last = -1
        for k in range(m + 1):
            if mask[w, k]:
                last = k
        # The filter's nominal attitude: the recorded one's chain when frozen, else the
        # current nominal.
        Rop[:, :] = op_R0[w] if frozen else Rbar[w, 0]
        start_window(Y, X, P, p, ns, rs, ts, R_WM0[w], Rop, M_op, Lk, par, cov)
        ld = 0.0
        for k in range(last + 1):
            if k > 0:
                j = k - 1
                hk = h[w, j]
                copy33(Rbar, w, j, Rk)
                transition_blocks(inc, w, j, Rk, Fc)
                Rstart[:, :] = Rop
                if frozen:
                    transition_blocks(op_inc, w, j, Rop, Fo)
                    chain(Rop, op_inc, w, j, Rnext)
                else:
                    Fo[:, :, :] = Fc
                    copy33(Rbar, w, k, Rop)
                a = step_lever(Rop, M_op, Lk, hk, ns, par)
                propagate(Y, X, P, p, ns, ni, hk, Fc, Fo, dwf, w, j, dg, gcols, a, par, tmp,
                          cov, Rstart)
            if not mask[w, k]:
                continue
            ld += whiten_sample(w, k, Y, X, P, N, Nw, PHt, HPHt, Sk, Lc, cov, Lk, p, ns, ni,
                                rs, ts, white, op_wts[w, k], par, r, Jinv, Pm_rot, Jp, Hq,
                                raw_J)
            use_sample(w, k, X, P, N, Nw, PHt, K, HPHt, Sk, Lc, Li, cov, p, nt, wts[w, k],
                       blocks, gram, innov, e_white, d_raw, scores, whitened)
        logdet[w] = ld
        if term_X.shape[0] > 0:  # the bias states at the window's end (mean per column, cov)
            term_X[w] = X[9:15, :p + 1]
            term_P[w] = P[9:15, 9:15]
        if ni > 0:
            int_X[w] = X[ns:nt, :p + 1]
            int_P[w, :, 0:6] = P[ns:nt, ns:nt]
            int_P[w, :, 6:12] = P[ns:nt, 9:15]
        for a in range(p + 1):
            for b in range(a):
                gram[w, a, b] = gram[w, b, a]
