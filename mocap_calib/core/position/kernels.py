"""The window filter's algebra, compiled and vectorised across windows (see
:mod:`mocap_calib.core.position.passes` for the pass itself).

The filter runs :data:`LANES` windows at once: every quantity carries a last axis over those
windows (lanes), and every operation is a loop over matrix entries whose innermost loop runs over
the lanes, which the compiler turns into vector instructions. Small matrices (3x3 blocks, the
6x6 innovation covariance) then cost as much per window as large ones.

The transition is built from a step's increments (its zero and identity blocks cost nothing),
the process noise from the densities and the mocap noise from the lever arm, so nothing of size
(windows x samples x states x states) is ever stored.

``par`` holds the noise: gyro and accel noise densities squared, their random walks squared, the
correlated fraction and time constant of the mocap noise (AR(1) states when both are positive)
and the six white mocap variances (attitude per IMU-frame axis, position per world axis).
"""

from __future__ import annotations

import numpy as np

from mocap_calib.core.jit import kernel

#: Windows filtered together (one vector register of doubles on AVX-512).
LANES = 8
#: Index of the noise parameters in ``par``.
Q_GYRO, Q_ACCEL, Q_GYRO_WALK, Q_ACCEL_WALK, RHO, T_CORR, SIG2 = 0, 1, 2, 3, 4, 5, 6
N_PAR = 12
#: Diffuse prior of a window's start state: attitude (rad), position (m), velocity (m/s).
DIFFUSE = (1.0, 1.0, 0.5)
#: Packed step increments (see preint.integrate_pieces): where dR, dv, dp, A, C, B, D start.
DR, DV, DP, IA, IC, IB, ID = 0, 9, 12, 15, 24, 33, 42
N_INC = 51

# ruff: noqa: N803, N806  (matrix names)


@kernel
def transition_blocks(inc, Rk, Fb):  # pragma: no cover  (compiled)
    """The non-trivial 3x3 blocks of a step's error-state transition, per lane, into ``Fb``
    (8, 3, 3, lanes): F00 = dR^T, F03 = -dR^T A, F10 = -Rk [dp]x, F13 = Rk D, F14 = -Rk C,
    F20 = -Rk [dv]x, F23 = Rk B, F24 = -Rk A (block rows: attitude, position, velocity; columns
    also gyro and accel bias). The rest: identity on the diagonal, ``h I`` at
    position/velocity. ``inc`` (51, lanes), ``Rk`` (3, 3, lanes)."""
    for i in range(3):
        for j in range(3):
            for v in range(LANES):
                Fb[0, i, j, v] = inc[DR + 3 * j + i, v]
    for i in range(3):
        for j in range(3):
            for v in range(LANES):
                f03 = f13 = f14 = f23 = f24 = 0.0
                for t in range(3):
                    f03 -= Fb[0, i, t, v] * inc[IA + 3 * t + j, v]
                    f13 += Rk[i, t, v] * inc[ID + 3 * t + j, v]
                    f14 -= Rk[i, t, v] * inc[IC + 3 * t + j, v]
                    f23 += Rk[i, t, v] * inc[IB + 3 * t + j, v]
                    f24 -= Rk[i, t, v] * inc[IA + 3 * t + j, v]
                Fb[1, i, j, v] = f03
                Fb[3, i, j, v] = f13
                Fb[4, i, j, v] = f14
                Fb[6, i, j, v] = f23
                Fb[7, i, j, v] = f24
        for blk, base in ((2, DP), (5, DV)):  # -Rk [x]x: column j of [x]x is e_j x x
            for v in range(LANES):
                x0, x1, x2 = inc[base, v], inc[base + 1, v], inc[base + 2, v]
                r0, r1, r2 = Rk[i, 0, v], Rk[i, 1, v], Rk[i, 2, v]
                Fb[blk, i, 0, v] = r2 * x1 - r1 * x2
                Fb[blk, i, 1, v] = r0 * x2 - r2 * x0
                Fb[blk, i, 2, v] = r1 * x0 - r0 * x1


@kernel
def phi_rows(Mx, nc, Fb, hk, ns, a, dL, tmp):  # pragma: no cover  (compiled)
    """``Mx[:, :nc] <- Phi Mx[:, :nc]`` in place, per lane: the error-state rows through the
    transition blocks ``Fb`` (``hk`` the step lengths); with AR(1) mocap states (``ns`` 21)
    those through ``a [[I, 0], [dL, I]]``."""
    for i in range(3):
        for c in range(nc):
            for v in range(LANES):
                tmp[i, c, v] = 0.0
                tmp[3 + i, c, v] = Mx[3 + i, c, v] + hk[v] * Mx[6 + i, c, v]
                tmp[6 + i, c, v] = Mx[6 + i, c, v]
        for t in range(3):
            for c in range(nc):
                for v in range(LANES):
                    x, bg, ba = Mx[t, c, v], Mx[9 + t, c, v], Mx[12 + t, c, v]
                    tmp[i, c, v] += Fb[0, i, t, v] * x + Fb[1, i, t, v] * bg
                    tmp[3 + i, c, v] += (Fb[2, i, t, v] * x + Fb[3, i, t, v] * bg
                                         + Fb[4, i, t, v] * ba)
                    tmp[6 + i, c, v] += (Fb[5, i, t, v] * x + Fb[6, i, t, v] * bg
                                         + Fb[7, i, t, v] * ba)
    for i in range(9):
        for c in range(nc):
            for v in range(LANES):
                Mx[i, c, v] = tmp[i, c, v]
    if ns == 21:
        ar_rows(Mx, nc, a, dL, tmp)


@kernel
def ar_rows(Mx, nc, a, dL, tmp):  # pragma: no cover  (compiled)
    """The AR(1) mocap states' rows 15:21 of ``Mx`` through ``a [[I, 0], [dL, I]]``."""
    for i in range(3):
        for c in range(nc):
            for v in range(LANES):
                tmp[i, c, v] = a[v] * (dL[i, 0, v] * Mx[15, c, v] + dL[i, 1, v] * Mx[16, c, v]
                                       + dL[i, 2, v] * Mx[17, c, v] + Mx[18 + i, c, v])
    for i in range(3):
        for c in range(nc):
            for v in range(LANES):
                Mx[15 + i, c, v] *= a[v]
                Mx[18 + i, c, v] = tmp[i, c, v]


@kernel
def mocap_cov(L, sig2, scale, out):  # pragma: no cover  (compiled)
    """``out`` (6, 6, lanes) = ``scale`` (per lane) times the covariance of a residual's mocap
    noise: attitude variances ``sig2[0:3]`` (IMU frame), position ``sig2[3:6]`` (world frame),
    the position error ``-L`` times the attitude noise (the lever arm)."""
    for i in range(3):
        for j in range(3):
            for v in range(LANES):
                LD = L[i, j, v] * sig2[j]
                out[i, j, v] = scale[v] * sig2[i] if i == j else 0.0
                out[3 + i, j, v] = -scale[v] * LD
                out[j, 3 + i, v] = -scale[v] * LD
                s = sig2[3 + i] if i == j else 0.0
                for t in range(3):
                    s += L[i, t, v] * sig2[t] * L[j, t, v]
                out[3 + i, 3 + j, v] = scale[v] * s


@kernel
def lever(R, M, L):  # pragma: no cover  (compiled)
    """``L = R M`` per lane (``M`` shared): d p_meas / d attitude noise at a sample with mocap
    attitude ``R``."""
    for i in range(3):
        for j in range(3):
            for v in range(LANES):
                L[i, j, v] = R[i, 0, v] * M[0, j] + R[i, 1, v] * M[1, j] + R[i, 2, v] * M[2, j]


@kernel
def predict_cov(P, ns, Fb, hk, a, dL, Lk, par, tmp, cov, qm):  # pragma: no cover  (compiled)
    """Filter covariance through a step: ``Phi P Phi^T`` plus the process noise (and the AR(1)
    states' innovation, ``rho (1 - a^2)`` of the mocap noise at the step's end sample)."""
    phi_rows(P, ns, Fb, hk, ns, a, dL, tmp)
    for i in range(ns):
        for j in range(i + 1, ns):
            for v in range(LANES):
                P[i, j, v], P[j, i, v] = P[j, i, v], P[i, j, v]
    phi_rows(P, ns, Fb, hk, ns, a, dL, tmp)
    sa2 = par[Q_ACCEL]
    for i in range(3):
        for v in range(LANES):
            h = hk[v]
            P[i, i, v] += par[Q_GYRO] * h
            P[3 + i, 3 + i, v] += sa2 * h * h * h / 3.0
            P[6 + i, 6 + i, v] += sa2 * h
            P[9 + i, 9 + i, v] += par[Q_GYRO_WALK] * h
            P[12 + i, 12 + i, v] += par[Q_ACCEL_WALK] * h
            P[3 + i, 6 + i, v] += sa2 * h * h / 2.0
            P[6 + i, 3 + i, v] += sa2 * h * h / 2.0
    if ns == 21:
        for v in range(LANES):
            qm[v] = par[RHO] * (1.0 - a[v] * a[v])
        mocap_cov(Lk, par[SIG2:SIG2 + 6], qm, cov)
        for i in range(6):
            for j in range(6):
                for v in range(LANES):
                    P[15 + i, 15 + j, v] += cov[i, j, v]


@kernel
def cholesky6(A, Lc, dinv, ld):  # pragma: no cover  (compiled)
    """Lower Cholesky factors ``Lc`` of the 6x6 ``A`` (per lane), the reciprocals of their
    diagonals ``dinv`` and ``ld`` = log det A."""
    for v in range(LANES):
        ld[v] = 1.0
    for j in range(6):
        for v in range(LANES):
            s = A[j, j, v]
            for t in range(j):
                s -= Lc[j, t, v] * Lc[j, t, v]
            d = np.sqrt(s)
            Lc[j, j, v] = d
            dinv[j, v] = 1.0 / d
            ld[v] *= s  # the product of the pivots: det A
        for i in range(j + 1, 6):
            for v in range(LANES):
                s = A[i, j, v]
                for t in range(j):
                    s -= Lc[i, t, v] * Lc[j, t, v]
                Lc[i, j, v] = s * dinv[j, v]
        for i in range(j):
            for v in range(LANES):
                Lc[i, j, v] = 0.0
    for v in range(LANES):
        ld[v] = np.log(ld[v])


@kernel
def forward(Lc, dinv, B, nc, out):  # pragma: no cover  (compiled)
    """``out[:, :nc] = Lc^-1 B[:, :nc]`` per lane (forward substitution, 6 rows)."""
    for i in range(6):
        for c in range(nc):
            for v in range(LANES):
                s = B[i, c, v]
                for t in range(i):
                    s -= Lc[i, t, v] * out[t, c, v]
                out[i, c, v] = s * dinv[i, v]


@kernel
def gain_update(X, P, Nw, PHt, Lc, dinv, U, ok, ns, p):  # pragma: no cover  (compiled)
    """Kalman update of mean and covariance in square-root form, in lanes where ``ok`` (1.0;
    0.0 elsewhere): with ``U = P H^T Lc^-T`` (``Lc`` the innovation covariance's Cholesky
    factor, ``Nw = Lc^-1 N`` the whitened rows), ``X += U Nw``, ``P -= U U^T``."""
    for i in range(ns):
        for t in range(6):
            for v in range(LANES):
                s = PHt[i, t, v]
                for u in range(t):
                    s -= U[i, u, v] * Lc[t, u, v]
                U[i, t, v] = s * dinv[t, v]
        for t in range(6):
            for v in range(LANES):
                U[i, t, v] *= ok[v]
    for i in range(ns):
        for t in range(6):
            for c in range(p + 1):
                for v in range(LANES):
                    X[i, c, v] += U[i, t, v] * Nw[t, c, v]
        for j in range(i, ns):
            for v in range(LANES):
                s = 0.0
                for t in range(6):
                    s += U[i, t, v] * U[j, t, v]
                P[i, j, v] -= s
                P[j, i, v] = P[i, j, v]
