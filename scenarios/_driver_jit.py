"""The numba-compiled loops of :mod:`pirl_sim.scenarios.driver_kernel` (imported only when a compiled kernel is
built: this module imports numba). Every function works on one driver or one point at a time; arrays are
float64 and C-contiguous; the module's doc and :class:`~pirl_sim.scenarios.driver_kernel.CompiledDriverMPC`
say what they compute.

Drivers who interact carry obstacles (the vehicle ahead, the obstacle yielded to): per driver ``ob`` (J, 2) holds
each obstacle's ``c0 = g_0 + s_0`` [m] and ``dt v_L`` [m], so that the gap at stage n is ``c0 + n dt v_L - s_n``
(the gap rows of `pirl_sim.dynamics.following` with the obstacle states eliminated), and ``hp`` (J, 3) the
residual's (d_0 [m], T [s], w [m]) of `pirl_sim.driving.HeadwayResidual`; their weights follow the paper's
three in ``th``. J = 0 is the paper's model. Per stage, ``hw`` (N, 8) holds what the obstacles add, weighted:
the gradient in (s, v), the Gauss-Newton block (ss, sv, vv) and the exact Hessian's extra block (ss, sv, vv)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_TOUCH_TOL = 1e-7  #: as `pirl_sim.mpc.BoxQP.touches`
_VIOLATION_TOL = 1e-9  #: as `pirl_sim.mpc.SequentialMPC.controls`

jit = njit(cache=True, nogil=True, error_model="numpy")  # divisions by zero as numpy: no checks


@jit
def softplus(z):
    """log(1 + e^z) computed as ``numpy.logaddexp(0, z)``."""
    if z == 0.0:
        return math.log(2.0)
    if z < 0.0:
        return math.log1p(math.exp(z))
    return z + math.log1p(math.exp(-z))


@jit
def obstacle_cost(s, v, n, ob, hp, th):
    """The obstacles' weighted residuals squared, theta_j r_j^2 summed over j, at stage n (state (s, v))."""
    f = 0.0
    for j in range(ob.shape[0]):
        w = hp[j, 2]
        z = (hp[j, 0] + hp[j, 1] * v - (ob[j, 0] + (n + 1) * ob[j, 1] - s)) / w
        r = w * softplus(z)
        f += th[3 + j] * (r * r)
    return f


@jit
def obstacle_terms(s, v, n, ob, hp, th, wsc, hw):
    """Row n of hw (see the module doc): what the obstacles add to stage n's gradient and Hessian in (s, v),
    each weighted by wsc theta_j; returns the weighted residuals squared as `obstacle_cost`."""
    f = 0.0
    for k in range(8):
        hw[n, k] = 0.0
    for j in range(ob.shape[0]):
        w, T = hp[j, 2], hp[j, 1]
        z = (hp[j, 0] + T * v - (ob[j, 0] + (n + 1) * ob[j, 1] - s)) / w
        r = w * softplus(z)
        sig = 0.5 * (1.0 + math.tanh(0.5 * z))
        f += th[3 + j] * (r * r)
        wj = wsc * th[3 + j]
        gs = wj * r * sig  # d/ds of theta_j r^2 / N: dr/ds = sig, dr/dv = T sig
        hg = wj * sig * sig
        he = wj * r * sig * (1.0 - sig) / w
        hw[n, 0] += gs
        hw[n, 1] += gs * T
        hw[n, 2] += hg
        hw[n, 3] += hg * T
        hw[n, 4] += hg * T * T
        hw[n, 5] += he
        hw[n, 6] += he * T
        hw[n, 7] += he * T * T
    return f


@jit
def locate(s, xb, hint):
    """The piece i of breaks xb (P+1,) holding s, clipped to [0, P - 1]: ``searchsorted(xb, s, "right") - 1``
    as `RouteSet.curvature`. From a hint (the piece of a nearby s: a walk) or, hint < 0, by bisection."""
    last = xb.shape[0] - 1
    if hint < 0:
        lo, hi = 0, xb.shape[0]  # first index with xb[i] > s
        while lo < hi:
            mid = (lo + hi) >> 1
            if xb[mid] > s:
                hi = mid
            else:
                lo = mid + 1
        i = lo - 1
    else:
        i = min(hint, last)
        while i < last and xb[i + 1] <= s:
            i += 1
        while i >= 0 and xb[i] > s:
            i -= 1
    if i < 0:
        i = 0
    elif i > last - 1:
        i = last - 1
    return i


@jit
def pieces(X, xb, idx, start):
    """The pieces idx (N,) of the piecewise cubic holding the arc lengths X[1:, 0] (`locate`, each walk from
    the previous piece, the first from ``start``, the piece of the start X[0, 0]). One pass of its own, so
    that the arithmetic of `vdes` runs without mispredicted branches."""
    h = start
    for n in range(idx.shape[0]):
        h = locate(X[n + 1, 0], xb, h)
        idx[n] = h


@jit
def vdes(s, i, xb, cf, inv_a4, vmax_m8):
    """v_des, dv_des/ds, d2v_des/ds2 at s in piece i (`pirl_sim.driving.desired_speed_along` of
    `RouteSet.curvature`, the piecewise cubic with breaks xb (P+1,) and coefficients cf (P, 4): one cache line
    per piece)."""
    t = s - xb[i]
    c0, c1, c2, c3 = cf[i, 0], cf[i, 1], cf[i, 2], cf[i, 3]
    k = ((c0 * t + c1) * t + c2) * t + c3
    dk = (3.0 * c0 * t + 2.0 * c1) * t + c2
    d2k = 6.0 * c0 * t + 2.0 * c1
    k2 = k * k
    k3 = k2 * k
    F = k2 * k2 * inv_a4 + vmax_m8
    v = 1.0 / math.sqrt(math.sqrt(math.sqrt(F)))  # F^(-1/8), within a few ulp of numpy.power, ~4x cheaper
    F98 = v / F
    F98F = F98 / F
    dv = -0.5 * inv_a4 * k3 * F98
    d2v = -1.5 * inv_a4 * k2 * F98 + 2.25 * inv_a4 * inv_a4 * (k3 * k3) * F98F
    return v, dv * dk, d2v * (dk * dk) + dv * d2k


@jit
def rollout(x0, U, Ad, Bd, X):
    """States X (N+1, 3) from x0 (3,) and jerks U (N,)."""
    X[0, 0], X[0, 1], X[0, 2] = x0[0], x0[1], x0[2]
    for n in range(U.shape[0]):
        u = U[n]
        for i in range(3):
            X[n + 1, i] = Ad[i, 0] * X[n, 0] + Ad[i, 1] * X[n, 1] + Ad[i, 2] * X[n, 2] + Bd[i] * u

@jit
def cost(x0, U, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, start):
    """theta . f at (x0, U); X (N+1, 3) and idx (N,) are work arrays, start the piece of x0[0] (< 0: unknown)."""
    N = U.shape[0]
    rollout(x0, U, Ad, Bd, X)
    pieces(X, xb, idx, locate(x0[0], xb, -1) if start < 0 else start)
    f0 = f1 = f2 = fo = 0.0
    for n in range(N):
        r = X[n + 1, 1] - vdes(X[n + 1, 0], idx[n], xb, cf, inv_a4, vmax_m8)[0]
        f0 += r * r
        f1 += X[n + 1, 2] * X[n + 1, 2]
        f2 += U[n] * U[n]
        if ob.shape[0]:
            fo += obstacle_cost(X[n + 1, 0], X[n + 1, 1], n, ob, hp, th)
    c = th[0] * (f0 / N) + th[1] * (f1 / N) + th[2] * (f2 / N)
    return c + fo / N if ob.shape[0] else c


@jit
def stages(x0, U, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, r, dvd, d2vd, hw, start):
    """Rollout X (N+1, 3), the speed residual with its derivatives per stage n = 1..N (into r, dvd, d2vd
    (N,)) and the obstacles' terms (into hw (N, 8); zeros without obstacles); returns the cost. idx (N,) is a
    work array, start the piece of x0[0] (< 0: unknown)."""
    N = U.shape[0]
    rollout(x0, U, Ad, Bd, X)
    pieces(X, xb, idx, locate(x0[0], xb, -1) if start < 0 else start)
    f0 = f1 = f2 = fo = 0.0
    wsc = 2.0 / N
    for n in range(N):
        fo += obstacle_terms(X[n + 1, 0], X[n + 1, 1], n, ob, hp, th, wsc, hw)
        vd, d1, d2 = vdes(X[n + 1, 0], idx[n], xb, cf, inv_a4, vmax_m8)
        r[n] = X[n + 1, 1] - vd
        dvd[n] = d1
        d2vd[n] = d2
        f0 += r[n] * r[n]
        f1 += X[n + 1, 2] * X[n + 1, 2]
        f2 += U[n] * U[n]
    c = th[0] * (f0 / N) + th[1] * (f1 / N) + th[2] * (f2 / N)
    return c + fo / N if ob.shape[0] else c


@jit
def stage_matrix(n, w0, w1, r, dvd, d2vd, hw, exact, S):
    """The state block S (3, 3) of stage n's Hessian (exact or Gauss-Newton)."""
    S[0, 0] = w0 * dvd[n] * dvd[n] + (w0 * r[n] * (-d2vd[n]) if exact else 0.0) + hw[n, 2]
    S[0, 1] = S[1, 0] = -w0 * dvd[n] + hw[n, 3]
    S[1, 1] = w0 + hw[n, 4]
    if exact:
        S[0, 0] += hw[n, 5]
        S[0, 1] += hw[n, 6]
        S[1, 0] = S[0, 1]
        S[1, 1] += hw[n, 7]
    S[0, 2] = S[2, 0] = S[1, 2] = S[2, 1] = 0.0
    S[2, 2] = w1

@jit
def riccati(th, U, X, r, dvd, d2vd, hw, Ad, Bd, exact, uu_share, with_step, step, Ks, ks):
    """Riccati recursion of the Newton model; True when every pivot is > 0 (the Hessian is positive
    definite). With ``with_step`` also the Newton step -H^-1 g into step (N,) (gains in Ks (N, 3), ks (N,)).

    Backwards over the stages, the cost-to-go 1/2 x'Px + p'x of x_{n+1} plus stage n+1's state terms
    (M = S + P, m = sigma + p) is mapped to (x_n, u_n) through x_{n+1} = A x_n + B u_n; u_n = K x_n + k
    minimises it. The stage Hessian's state block is [[ss, sv, 0], [sv, vv, 0], [0, 0, aa]] (speed_dev, the
    obstacles and acc_sq), its control entry uu_share * w2 (jerk_sq)."""
    N = U.shape[0]
    wsc = 2.0 / N
    w0, w1, w2 = wsc * th[0], wsc * th[1], wsc * th[2]
    quu_ref = uu_share * w2
    a00, a01, a02 = Ad[0, 0], Ad[0, 1], Ad[0, 2]
    a10, a11, a12 = Ad[1, 0], Ad[1, 1], Ad[1, 2]
    a20, a21, a22 = Ad[2, 0], Ad[2, 1], Ad[2, 2]
    b0, b1, b2 = Bd[0], Bd[1], Bd[2]
    # P (symmetric) and p: the cost-to-go of x_{n+1}
    p00 = p01 = p02 = p11 = p12 = p22 = 0.0
    q0 = q1 = q2 = 0.0
    ok = True
    for n in range(N - 1, -1, -1):
        ss = w0 * dvd[n] * dvd[n]
        if exact:
            ss += w0 * r[n] * (-d2vd[n])
        ss += hw[n, 2]
        sv = -w0 * dvd[n] + hw[n, 3]
        vv = w0 + hw[n, 4]
        if exact:
            ss += hw[n, 5]
            sv += hw[n, 6]
            vv += hw[n, 7]
        m00, m01, m02 = ss + p00, sv + p01, p02
        m11, m12, m22 = vv + p11, p12, w1 + p22
        # MA = M A (3 x 3), MB = M B
        ma00 = m00 * a00 + m01 * a10 + m02 * a20
        ma01 = m00 * a01 + m01 * a11 + m02 * a21
        ma02 = m00 * a02 + m01 * a12 + m02 * a22
        ma10 = m01 * a00 + m11 * a10 + m12 * a20
        ma11 = m01 * a01 + m11 * a11 + m12 * a21
        ma12 = m01 * a02 + m11 * a12 + m12 * a22
        ma20 = m02 * a00 + m12 * a10 + m22 * a20
        ma21 = m02 * a01 + m12 * a11 + m22 * a21
        ma22 = m02 * a02 + m12 * a12 + m22 * a22
        mb0 = m00 * b0 + m01 * b1 + m02 * b2
        mb1 = m01 * b0 + m11 * b1 + m12 * b2
        mb2 = m02 * b0 + m12 * b1 + m22 * b2
        quu = b0 * mb0 + b1 * mb1 + b2 * mb2 + quu_ref
        if not quu > 0.0:
            ok = False
            if not with_step:
                return False
        # Q_ux = B' M A = (M B)' A
        qux0 = mb0 * a00 + mb1 * a10 + mb2 * a20
        qux1 = mb0 * a01 + mb1 * a11 + mb2 * a21
        qux2 = mb0 * a02 + mb1 * a12 + mb2 * a22
        inv = 1.0 / quu
        K0, K1, K2 = -qux0 * inv, -qux1 * inv, -qux2 * inv
        # P <- A' M A + Q_ux' K
        p00 = a00 * ma00 + a10 * ma10 + a20 * ma20 + qux0 * K0
        p01 = a00 * ma01 + a10 * ma11 + a20 * ma21 + qux0 * K1
        p02 = a00 * ma02 + a10 * ma12 + a20 * ma22 + qux0 * K2
        p11 = a01 * ma01 + a11 * ma11 + a21 * ma21 + qux1 * K1
        p12 = a01 * ma02 + a11 * ma12 + a21 * ma22 + qux1 * K2
        p22 = a02 * ma02 + a12 * ma12 + a22 * ma22 + qux2 * K2
        if with_step:
            # the stage gradient in x_{n+1} plus the cost-to-go's linear term
            g0 = w0 * r[n] * (-dvd[n]) + hw[n, 0] + q0
            g1 = w0 * r[n] + hw[n, 1] + q1
            g2 = w1 * X[n + 1, 2] + q2
            qu = b0 * g0 + b1 * g1 + b2 * g2 + w2 * U[n]
            kk = -qu * inv
            q0 = a00 * g0 + a10 * g1 + a20 * g2 + qux0 * kk
            q1 = a01 * g0 + a11 * g1 + a21 * g2 + qux1 * kk
            q2 = a02 * g0 + a12 * g1 + a22 * g2 + qux2 * kk
            Ks[n, 0], Ks[n, 1], Ks[n, 2] = K0, K1, K2
            ks[n] = kk
    if with_step:
        d0 = d1 = d2 = 0.0
        for n in range(N):
            du = Ks[n, 0] * d0 + Ks[n, 1] * d1 + Ks[n, 2] * d2 + ks[n]
            step[n] = du
            d0, d1, d2 = (a00 * d0 + a01 * d1 + a02 * d2 + b0 * du,
                          a10 * d0 + a11 * d1 + a12 * d2 + b1 * du,
                          a20 * d0 + a21 * d1 + a22 * d2 + b2 * du)
    return ok


@jit
def exact_ok(th, U, X, r, dvd, d2vd, hw, Ad, Bd, step, Ks, ks):
    """Whether the exact Hessian with half the reference term is positive definite (`SequentialMPC._model`'s
    test). Every stage's state block [[w0 (dvd^2 - r d2vd), -w0 dvd, 0], [-w0 dvd, w0, 0], [0, 0, w1]] is
    positive semi-definite where r d2vd <= 0 (its determinant in (s, v) is -w0^2 r d2vd), the obstacles'
    blocks always are, and then the Hessian, their sum plus the reference term's positive diagonal, is
    positive definite: the recursion's pivots are tested only when some stage has r d2vd > 0."""
    for n in range(U.shape[0]):
        if r[n] * d2vd[n] > 0.0:
            return riccati(th, U, X, r, dvd, d2vd, hw, Ad, Bd, True, 0.5, False, step, Ks, ks)
    return True


@jit
def newton_step(th, U, X, r, dvd, d2vd, hw, Ad, Bd, step, Ks, ks):
    """The Newton step (N,) of `pirl_sim.mpc.SequentialMPC._model`: exact where the exact Hessian with
    half the reference term is positive definite, Gauss-Newton elsewhere."""
    if exact_ok(th, U, X, r, dvd, d2vd, hw, Ad, Bd, step, Ks, ks):
        riccati(th, U, X, r, dvd, d2vd, hw, Ad, Bd, True, 1.0, True, step, Ks, ks)
    else:
        riccati(th, U, X, r, dvd, d2vd, hw, Ad, Bd, False, 1.0, True, step, Ks, ks)

@jit
def dense_model(x0, th, ob, hp, U, Ad, Bd, xb, cf, inv_a4, vmax_m8, H, b):
    """The dense Newton model at U: H (N, N) and b (N,) of 1/2 U'HU + b'U (`SequentialMPC._model`)."""
    N = U.shape[0]
    X = np.empty((N + 1, 3))
    idx = np.empty(N, dtype=np.int64)
    r, dvd, d2vd = np.empty(N), np.empty(N), np.empty(N)
    hw = np.empty((N, 8))
    stages(x0, U, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, r, dvd, d2vd, hw, -1)
    dummy_s, dummy_K, dummy_k = np.empty(N), np.empty((N, 3)), np.empty(N)
    exact = exact_ok(th, U, X, r, dvd, d2vd, hw, Ad, Bd, dummy_s, dummy_K, dummy_k)
    wsc = 2.0 / N
    w0, w1, w2 = wsc * th[0], wsc * th[1], wsc * th[2]
    # Psi_k = A^k B (N, 3)
    Psi = np.empty((N, 3))
    Psi[0, 0], Psi[0, 1], Psi[0, 2] = Bd[0], Bd[1], Bd[2]
    for k in range(1, N):
        for i in range(3):
            Psi[k, i] = Ad[i, 0] * Psi[k - 1, 0] + Ad[i, 1] * Psi[k - 1, 1] + Ad[i, 2] * Psi[k - 1, 2]
    L = np.zeros((3, 3))
    LA = np.empty((3, 3))
    S = np.empty((3, 3))
    lam = np.zeros(3)
    y = np.empty(3)
    g = np.empty(N)
    for j in range(N - 1, -1, -1):
        # L_j = S_{j+1} + A' L_{j+1} A ; lambda_j = sigma_{j+1} + A' lambda_{j+1}
        stage_matrix(j, w0, w1, r, dvd, d2vd, hw, exact, S)
        if j < N - 1:
            for i in range(3):
                for k in range(3):
                    LA[i, k] = L[i, 0] * Ad[0, k] + L[i, 1] * Ad[1, k] + L[i, 2] * Ad[2, k]
            for i in range(3):
                for k in range(3):
                    L[i, k] = S[i, k] + Ad[0, i] * LA[0, k] + Ad[1, i] * LA[1, k] + Ad[2, i] * LA[2, k]
            l0 = Ad[0, 0] * lam[0] + Ad[1, 0] * lam[1] + Ad[2, 0] * lam[2]
            l1 = Ad[0, 1] * lam[0] + Ad[1, 1] * lam[1] + Ad[2, 1] * lam[2]
            l2 = Ad[0, 2] * lam[0] + Ad[1, 2] * lam[1] + Ad[2, 2] * lam[2]
        else:
            for i in range(3):
                for k in range(3):
                    L[i, k] = S[i, k]
            l0 = l1 = l2 = 0.0
        lam[0] = l0 + w0 * r[j] * (-dvd[j]) + hw[j, 0]
        lam[1] = l1 + w0 * r[j] + hw[j, 1]
        lam[2] = l2 + w1 * X[j + 1, 2]
        g[j] = Bd[0] * lam[0] + Bd[1] * lam[1] + Bd[2] * lam[2] + w2 * U[j]
        for i in range(3):
            y[i] = L[i, 0] * Bd[0] + L[i, 1] * Bd[1] + L[i, 2] * Bd[2]
        for i in range(j + 1):
            q = Psi[j - i]
            H[i, j] = q[0] * y[0] + q[1] * y[1] + q[2] * y[2]
            H[j, i] = H[i, j]
        H[j, j] += w2
    for i in range(N):
        acc = 0.0
        for j in range(N):
            acc += H[i, j] * U[j]
        b[i] = g[i] - acc

@jit
def violation(x0, U, X, Ad, Bd, xlo, xhi, ulo, uhi):
    """Largest bound violation of the plan (0 when feasible), as `BoxQP.violation`."""
    rollout(x0, U, Ad, Bd, X)
    v = 0.0
    for n in range(1, X.shape[0]):
        for i in range(3):
            v = max(v, xlo[i] - X[n, i], X[n, i] - xhi[i])
    for n in range(U.shape[0]):
        v = max(v, ulo - U[n], U[n] - uhi)
    return v

@jit
def touches(x0, U, X, Ad, Bd, xlo, xhi, ulo, uhi, tol):
    """Whether the plan sits on a bound, as `BoxQP.touches`."""
    rollout(x0, U, Ad, Bd, X)
    for n in range(1, X.shape[0]):
        for i in range(3):
            if abs(X[n, i] - xlo[i]) <= tol or abs(X[n, i] - xhi[i]) <= tol:
                return True
    for n in range(U.shape[0]):
        if abs(U[n] - ulo) <= tol or abs(U[n] - uhi) <= tol:
            return True
    return False

@jit
def newton_batch(x0s, ths, obs, hp, Us, Ad, Bd, xb, cf, inv_a4, vmax_m8, xlo, xhi, ulo, uhi, n_iter, tol,
                 on_bounds, bad, counts):
    """The Newton phase of `SequentialMPC.controls` for every driver (rows of Us changed in place), then
    the drivers needing bounded QPs (``bad``: the plan breaks a bound or the warm start sits on one).
    obs (M, J, 2): each driver's obstacles (module doc). counts[0] += Newton steps taken."""
    M, N = Us.shape
    X = np.empty((N + 1, 3))
    idx = np.empty(N, dtype=np.int64)
    r, dvd, d2vd = np.empty(N), np.empty(N), np.empty(N)
    full, trial = np.empty(N), np.empty(N)
    Ks, ks = np.empty((N, 3)), np.empty(N)
    hw = np.empty((N, 8))
    for m in range(M):
        x0, th, ob, U = x0s[m], ths[m], obs[m], Us[m]
        on_bounds[m] = touches(x0, U, X, Ad, Bd, xlo, xhi, ulo, uhi, _TOUCH_TOL)
        if not on_bounds[m]:
            start = locate(x0[0], xb, -1)
            c = stages(x0, U, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, r, dvd, d2vd, hw, start)
            for _it in range(n_iter):
                newton_step(th, U, X, r, dvd, d2vd, hw, Ad, Bd, full, Ks, ks)
                counts[0] += 1
                limit = c + 1e-12 * abs(c)
                alpha = 1.0
                for n in range(N):
                    trial[n] = U[n] + full[n]
                tc = cost(x0, trial, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, start)
                for _half in range(6):
                    if not tc > limit:
                        break
                    alpha *= 0.5
                    for n in range(N):
                        trial[n] = U[n] + alpha * full[n]
                    tc = cost(x0, trial, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, start)
                if tc > limit:  # not accepted: the controls stay, the iteration stops
                    break
                big = 0.0
                for n in range(N):
                    big = max(big, abs(full[n]))
                    U[n] = trial[n]
                if not alpha * big > tol:
                    break
                c = stages(x0, U, th, ob, hp, Ad, Bd, xb, cf, inv_a4, vmax_m8, X, idx, r, dvd, d2vd, hw, start)
        bad[m] = on_bounds[m] or violation(x0, U, X, Ad, Bd, xlo, xhi, ulo, uhi) > _VIOLATION_TOL

@jit
def frame(r, s, base, nrow, inv_step, length, rows):
    """`RouteSet._frame` for one point: x, y, dx/ds, dy/ds, heading, dheading/ds."""
    n = nrow[r]
    j = int(s * inv_step[r])
    if j > n - 2:
        j = n - 2
    if j < 0:
        j = 0
    g = base[r] + j
    ds = rows[g + 1, 0] - rows[g, 0]
    u = (s - rows[g, 0]) / ds
    if u < 0.0:
        u = 0.0
    elif u > 1.0:
        u = 1.0
    dxr = rows[g + 1, 1] - rows[g, 1]
    dyr = rows[g + 1, 2] - rows[g, 2]
    dhr = rows[g + 1, 3] - rows[g, 3]
    x = rows[g, 1] + u * dxr
    y = rows[g, 2] + u * dyr
    h = rows[g, 3] + u * dhr
    dx, dy, dh = dxr / ds, dyr / ds, dhr / ds
    if s < 0.0 or s > length[r]:
        e = base[r] if s < 0.0 else base[r] + n - 1
        over = s if s < 0.0 else s - length[r]
        h = rows[e, 3]
        c, sn = math.cos(h), math.sin(h)
        x = rows[e, 1] + over * c
        y = rows[e, 2] + over * sn
        dx, dy, dh = c, sn, 0.0
    return x, y, dx, dy, h, dh

@jit
def project(ri, q, s, base, nrow, inv_step, step_len, length, rows, tol, max_iter, min_slope, work):
    """`RouteSet.project` from finite starts s (changed in place): Newton on the foot-point condition, all
    points until no point moves more than tol. Returns the iterations taken, or -1 - k when point k had
    not converged after max_iter."""
    M = s.shape[0]
    for it in range(max_iter):
        big = 0.0
        for m in range(M):
            x, y, dx, dy, h, dh = frame(ri[m], s[m], base, nrow, inv_step, length, rows)
            c, sn = math.cos(h), math.sin(h)
            rx, ry = q[m, 0] - x, q[m, 1] - y
            f = rx * c + ry * sn
            fp = -(dx * c + dy * sn) + dh * (-rx * sn + ry * c)
            st = -f / min(fp, min_slope)
            cap = step_len[ri[m]]
            if st > cap:
                st = cap
            elif st < -cap:
                st = -cap
            s[m] = s[m] + st
            work[m] = st
            big = max(big, abs(st))
        if big <= tol:
            return it + 1
    k = 0
    for m in range(M):
        if abs(work[m]) > abs(work[k]):
            k = m
    return -1 - k
