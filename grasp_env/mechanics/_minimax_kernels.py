"""Numba kernels of the certified minimax solver; the method is described in ``minimax.py``.

One problem: n <= 4 fingers, m = n (n - 1) / 2 <= 6 interaction scalars. Each finger is
written in its own frame (inward normal n_i, tangential basis b_i, c_i): with the forces
divided by ``scale`` (the largest equilibrating force),

    a_i(k) = a0_i + al_i . k          normal component n_i . P_i
    tau_i(k) = tau0_i + T_i k         tangential components (b_i . P_i, c_i . P_i)
    theta_i = atan2(|tau_i|, a_i)     paper eq. 2

and |P_i| = sqrt(a_i^2 + |tau_i|^2). Every routine works on these arrays.
"""

from __future__ import annotations

from math import atan, atan2, cos, inf, isfinite, log, pi, sin, sqrt

import numpy as np
from numba import njit

#: Accepted certificate gap, radians (1e-6 deg is 1.7e-8 rad).
GAP_TOL = 1e-9
#: Offsets below the primal value at which the dual certificate is tried, radians.
_DELTAS = (1e-11, 1e-10, 5e-10)
INTERIOR, BOUNDARY, NOT_PUSHING = 0, 1, 2
APEX, UNCERTIFIED, INVALID = 0, 6, -1  # diagnostic paths (see solve_one)
# inputs refused (see solve_one): a normal not of unit length, a load or a k_max / f_max
# outside the ranges below
BAD_NORMAL, BAD_LOAD, BAD_K_MAX, BAD_F_MAX = -2, -3, -4, -5
#: Accepted scale of the load, the largest equilibrating force (newtons), besides 0.
LOAD_RANGE = (1e-305, 1e305)
#: Accepted k_max and f_max in units of the load: beyond them float64 cannot hold the
#: equilibrating forces beside the interaction forces (or the reverse).
RATIO_RANGE = (1e-12, 1e12)
#: Accepted deviation of a normal's length from 1.
UNIT_TOL = 1e-6
#: A released finger (zero force at the optimum) is held at this normal force (normalised),
#: inside its cone, so that its friction angle is well defined.
RELEASE = 1e-10
#: Newton's KKT residual that an attempt from a far start must reach within its first few
#: iterations (see polish): one that has not is rarely converging, and costs as much as the SQP.
SETTLED = 1e-4
#: Starting from a nearby grasp's optimum, the fingers within this of the largest friction
#: angle are taken as the maximum (radians, about 6 deg; finish repairs a wrong guess at the
#: cost of a polish, where a finger missed would cost the SQP).
NEAR_ANGLES = 0.1

# Compile time: numba links every callee's code into each caller and compiles it again, so
# the attempts and small helpers are inlined and only the entry point gets a Python wrapper.
_jit = njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
_small = njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, inline="always")
_inline = njit(
    cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, inline="always"
)
_entry = njit(cache=True, nogil=True, error_model="numpy")


@_jit
def setup(F, E, N, a0, al, tau0, T):
    """Fill the finger-frame arrays from world-frame F (n,3), E (m,n,3), N (n,3).

    Returns (scale, code): scale is the largest equilibrating force |F_i| (the unit of the
    arrays; 0 for no load, when the arrays are left unfilled) and code BAD_NORMAL if a
    normal is not a unit vector, else 0.
    """
    n = F.shape[0]
    m = E.shape[0]
    for i in range(n):
        nn = sqrt(N[i, 0] ** 2 + N[i, 1] ** 2 + N[i, 2] ** 2)
        if not abs(nn - 1.0) <= UNIT_TOL:
            return 0.0, BAD_NORMAL
    # |F_i| without squaring F (which under- or overflows beyond about 1e+-154)
    big = 0.0
    for i in range(n):
        for c in range(3):
            big = max(big, abs(F[i, c]))
    if big == 0.0:
        return 0.0, 0
    scale = 0.0
    for i in range(n):
        s = big * sqrt((F[i, 0] / big) ** 2 + (F[i, 1] / big) ** 2 + (F[i, 2] / big) ** 2)
        scale = max(scale, s)
    for i in range(n):
        nx, ny, nz = N[i, 0], N[i, 1], N[i, 2]
        nn = sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        # b = n x (the axis least aligned with n), normalised; c = n x b
        if abs(nx) <= abs(ny) and abs(nx) <= abs(nz):
            bx, by, bz = 0.0, nz, -ny
        elif abs(ny) <= abs(nz):
            bx, by, bz = -nz, 0.0, nx
        else:
            bx, by, bz = ny, -nx, 0.0
        bn = sqrt(bx * bx + by * by + bz * bz)
        bx, by, bz = bx / bn, by / bn, bz / bn
        cx, cy, cz = ny * bz - nz * by, nz * bx - nx * bz, nx * by - ny * bx
        f0, f1, f2 = F[i, 0] / scale, F[i, 1] / scale, F[i, 2] / scale
        a0[i] = nx * f0 + ny * f1 + nz * f2
        tau0[i, 0] = bx * f0 + by * f1 + bz * f2
        tau0[i, 1] = cx * f0 + cy * f1 + cz * f2
        for j in range(m):
            e0, e1, e2 = E[j, i, 0], E[j, i, 1], E[j, i, 2]
            al[i, j] = nx * e0 + ny * e1 + nz * e2
            T[i, 0, j] = bx * e0 + by * e1 + bz * e2
            T[i, 1, j] = cx * e0 + cy * e1 + cz * e2
    return scale, 0


@_small
def all_finite(x):
    for value in x.ravel():
        if not isfinite(value):
            return False
    return True


@_small
def zero(A):
    for p in range(A.shape[0]):
        for q in range(A.shape[1]):
            A[p, q] = 0.0


@_small
def copy_into(dst, src, count):
    for j in range(count):
        dst[j] = src[j]


@_small
def angle(tangential, normal):
    """atan2(tangential, normal) for tangential >= 0; atan where it agrees (twice as fast)."""
    if normal > 0.0:
        return atan(tangential / normal)
    return atan2(tangential, normal)


@_jit
def evaluate(k, a0, al, tau0, T, a, tau, rho, theta):
    """Normal and tangential components, |tau| and theta at k; returns max theta."""
    n, m = al.shape
    worst = -1.0
    for i in range(n):
        s, t0, t1 = a0[i], tau0[i, 0], tau0[i, 1]
        for j in range(m):
            s += al[i, j] * k[j]
            t0 += T[i, 0, j] * k[j]
            t1 += T[i, 1, j] * k[j]
        a[i] = s
        tau[i, 0] = t0
        tau[i, 1] = t1
        rho[i] = sqrt(t0 * t0 + t1 * t1)
        theta[i] = angle(rho[i], s)
        if theta[i] > worst:
            worst = theta[i]
    return worst


@_jit
def lu_solve(A, b, size):
    """Solve A x = b in place (b <- x) by Gaussian elimination with partial pivoting.

    Returns False for a (numerically) singular matrix.
    """
    big = 0.0
    for r in range(size):
        for c in range(size):
            big = max(big, abs(A[r, c]))
    if big == 0.0:
        return False
    for c in range(size):
        p = c
        for r in range(c + 1, size):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if abs(A[p, c]) <= 1e-14 * big:
            return False
        if p != c:
            for cc in range(size):
                A[c, cc], A[p, cc] = A[p, cc], A[c, cc]
            b[c], b[p] = b[p], b[c]
        for r in range(c + 1, size):
            f = A[r, c] / A[c, c]
            if f != 0.0:
                for cc in range(c + 1, size):
                    A[r, cc] -= f * A[c, cc]
                b[r] -= f * b[c]
    for c in range(size - 1, -1, -1):
        s = b[c]
        for cc in range(c + 1, size):
            s -= A[c, cc] * b[cc]
        b[c] = s / A[c, c]
    return True


@_jit
def cholesky_inverse(H, size, out, L, Li):
    """out <- H^-1 for symmetric H via Cholesky (L, Li scratch); False unless H is positive
    definite."""
    for r in range(size):
        for c in range(size):
            L[r, c] = 0.0
            Li[r, c] = 0.0
    for j in range(size):
        s = H[j, j]
        for q in range(j):
            s -= L[j, q] * L[j, q]
        if s <= 1e-14 * max(1.0, abs(H[j, j])):
            return False
        L[j, j] = sqrt(s)
        for r in range(j + 1, size):
            s = H[r, j]
            for q in range(j):
                s -= L[r, q] * L[j, q]
            L[r, j] = s / L[j, j]
    # invert L (lower triangular), then out = L^-T L^-1
    for j in range(size):
        Li[j, j] = 1.0 / L[j, j]
        for r in range(j + 1, size):
            s = 0.0
            for q in range(j, r):
                s -= L[r, q] * Li[q, j]
            Li[r, j] = s / L[r, r]
    for r in range(size):
        for c in range(size):
            s = 0.0
            for q in range(max(r, c), size):
                s += Li[q, r] * Li[q, c]
            out[r, c] = s
    return True


@_jit
def quadprog(Ginv, c, C, b, nc, meq, dim, x, u, GN, M, vec, active, is_active):
    """Goldfarb-Idnani dual active-set method: min 1/2 x'Gx + c'x subject to C x >= b.

    The first ``meq`` rows are equalities C x = b (their rows may be negated in place).
    ``Ginv`` is G^-1 (G positive definite). Fills x and the multipliers u (nc). The active
    set is kept explicitly and the projections are recomputed from it at each step, which
    at these sizes (dim <= 7) is as cheap as updating factorisations and simpler.
    Scratch: GN, M (dim, dim), vec (6, >= max(dim, nc)), active (dim), is_active (nc).
    Returns 0, or a positive code if the constraints are infeasible (or a limit is hit).
    """
    for i in range(dim):
        s = 0.0
        for j in range(dim):
            s -= Ginv[i, j] * c[j]
        x[i] = s
    for i in range(nc):
        u[i] = 0.0
    ua = vec[0]
    r = vec[1]
    y = vec[2]
    z = vec[3]
    cnorm = vec[4]
    sign = vec[5]
    for i in range(nc):
        is_active[i] = False
        sign[i] = 1.0
    q = 0
    for i in range(nc):
        s = 0.0
        for j in range(dim):
            s += C[i, j] * C[i, j]
        cnorm[i] = sqrt(s)
    for _ in range(4 * (nc + dim)):
        p = -1
        worst = 0.0
        for i in range(meq):
            if not is_active[i]:
                p = i
                s = -b[i]
                for j in range(dim):
                    s += C[i, j] * x[j]
                if s > 0.0:  # approach the equality from its violated side
                    b[i] = -b[i]
                    for j in range(dim):
                        C[i, j] = -C[i, j]
                    sign[i] = -1.0
                break
        for i in range(nc if p < 0 else 0):
            if not is_active[i]:
                s = -b[i]
                for j in range(dim):
                    s += C[i, j] * x[j]
                s /= cnorm[i]
                if s < worst - 1e-13 * (1.0 + abs(b[i]) / cnorm[i]):
                    worst = s
                    p = i
        if p < 0:
            for a_ in range(q):
                u[active[a_]] = ua[a_] * sign[active[a_]]
            return 0
        up = 0.0
        for _inner in range(2 * dim + 2):
            for i in range(dim):
                s = 0.0
                for j in range(dim):
                    s += Ginv[i, j] * C[p, j]
                y[i] = s
            for a_ in range(q):
                row = active[a_]
                for i in range(dim):
                    s = 0.0
                    for j in range(dim):
                        s += Ginv[i, j] * C[row, j]
                    GN[i, a_] = s
            for a_ in range(q):
                s = 0.0
                for j in range(dim):
                    s += C[active[a_], j] * y[j]
                r[a_] = s
                for b_ in range(q):
                    s = 0.0
                    for j in range(dim):
                        s += C[active[a_], j] * GN[j, b_]
                    M[a_, b_] = s
            if q > 0 and not lu_solve(M, r, q):
                return 1
            zn = 0.0
            zz = 0.0
            for i in range(dim):
                s = y[i]
                for a_ in range(q):
                    s -= GN[i, a_] * r[a_]
                z[i] = s
                zn += s * C[p, i]
                zz += s * s
            t1 = inf
            kd = -1
            for a_ in range(q):
                if active[a_] >= meq and r[a_] > 1e-14:
                    ratio = ua[a_] / r[a_]
                    if ratio < t1:
                        t1 = ratio
                        kd = a_
            sp = -b[p]
            for j in range(dim):
                sp += C[p, j] * x[j]
            if q < dim and zn > 1e-12 * cnorm[p] * sqrt(zz) and zz > 0.0:
                t2 = -sp / zn
            else:
                t2 = inf
            t = min(t1, t2)
            if t == inf:
                return 2
            for a_ in range(q):
                ua[a_] -= t * r[a_]
            up += t
            if t2 < inf:
                for i in range(dim):
                    x[i] += t * z[i]
            if t2 <= t1:
                active[q] = p
                ua[q] = up
                is_active[p] = True
                q += 1
                break
            # drop constraint kd (partial step) and continue with p
            is_active[active[kd]] = False
            for a_ in range(kd, q - 1):
                active[a_] = active[a_ + 1]
                ua[a_] = ua[a_ + 1]
            q -= 1
        else:
            return 3
    return 4


@_jit
def finger_derivatives(exact, i, w, a, tau, rho, al, T, grad, H):
    """theta_i(k) (paper eq. 2), its gradient (into grad) and w x its Hessian (added to H).

    With exact = 0.0 only the convex, circumferential part of the Hessian is added (the
    curvature of the cone |tau| <= tan(t) a), a positive semidefinite stand-in that the SQP
    uses far from the optimum; exact = 1.0 gives the true Hessian for Newton's method.
    """
    m = al.shape[1]
    ai, ri = a[i], rho[i]
    if ri > 0.0:
        u0, u1 = tau[i, 0] / ri, tau[i, 1] / ri
    else:
        u0, u1 = 1.0, 0.0
    r2 = ri * ri + ai * ai
    for j in range(m):
        grad[j] = (ai * (T[i, 0, j] * u0 + T[i, 1, j] * u1) - ri * al[i, j]) / r2
    if w != 0.0:
        c1 = w * (ai if exact > 0.0 else abs(ai)) / (r2 * max(ri, 1e-300))
        c2 = exact * w * (ri * ri - ai * ai) / (r2 * r2)
        c3 = exact * w * 2.0 * ai * ri / (r2 * r2)
        for p in range(m):
            gr_p = T[i, 0, p] * u0 + T[i, 1, p] * u1
            gv_p = T[i, 1, p] * u0 - T[i, 0, p] * u1
            for q in range(m):
                gr_q = T[i, 0, q] * u0 + T[i, 1, q] * u1
                gv_q = T[i, 1, q] * u0 - T[i, 0, q] * u1
                H[p, q] += (
                    c1 * gv_p * gv_q
                    + c2 * (gr_p * al[i, q] + al[i, p] * gr_q)
                    + c3 * (al[i, p] * al[i, q] - gr_p * gr_q)
                )
    return angle(ri, ai)


@_jit
def force_derivatives(i, w, a, tau, al, T, grad, H):
    """|P_i|, its gradient (into grad) and w x its Hessian (added to H)."""
    m = al.shape[1]
    P = sqrt(a[i] ** 2 + tau[i, 0] ** 2 + tau[i, 1] ** 2)
    Ps = max(P, 1e-300)
    v0, v1, v2 = a[i] / Ps, tau[i, 0] / Ps, tau[i, 1] / Ps
    for j in range(m):
        grad[j] = v0 * al[i, j] + v1 * T[i, 0, j] + v2 * T[i, 1, j]
    if w != 0.0:
        for p in range(m):
            for q in range(m):
                AtA = al[i, p] * al[i, q] + T[i, 0, p] * T[i, 0, q] + T[i, 1, p] * T[i, 1, q]
                H[p, q] += w * (AtA - grad[p] * grad[q]) / Ps
    return P


@_small
def merit(k, a0, al, tau0, T, f, penalty, R, a, tau, rho, theta):
    """max theta_i over the fingers not released, plus the penalised force-limit excess."""
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    worst = -inf
    for i in range(al.shape[0]):
        if not R[i]:
            worst = max(worst, theta[i])
        if f < inf:
            excess = sqrt(a[i] ** 2 + rho[i] ** 2) - f
            if excess > 0.0:
                worst += penalty * excess
    return worst


@_jit
def sqp(a0, al, tau0, T, K, f, R, release, k, lam, nu, max_iter, tol):
    """SQP for min t s.t. theta_i(k) <= t, |k_j| <= K, |P_i| <= f, from k inside the box.

    Released fingers (R) are held at P_i = release * n_i (k must satisfy this on entry).
    Each step solves the QP  min z + z^2 / 2 + d'Hd / 2  subject to
    theta_i + grad_i . d <= theta_max + z, the box, the linearised force limits and the
    released fingers' A_i d = 0, with H the Lagrangian Hessian convexified, then backtracks
    on the merit max_i theta_i. Updates k, lam (the theta multipliers, summing to 1) and nu;
    returns the number of steps taken, or < 0 if a QP failed.
    """
    n, m = al.shape
    has_f = f < inf
    dim = m + 1
    nr = 0
    for i in range(n):
        nr += R[i]
    meq = 3 * nr
    nc = meq + (n - nr) + 2 * m + (n if has_f else 0)
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    grads = np.zeros((n, m))
    fgrads = np.empty((n, m))
    P = np.empty(n)
    H = np.empty((m, m))
    Hs = np.empty((m, m))
    Hinv = np.empty((m, m))
    Ginv = np.zeros((dim, dim))
    c = np.zeros(dim)
    c[m] = 1.0
    C = np.zeros((nc, dim))
    b = np.empty(nc)
    x = np.empty(dim)
    u = np.empty(nc)
    k_try = np.empty(m)
    gmean = np.empty(m)
    Lc = np.empty((m, m))
    Lic = np.empty((m, m))
    GN = np.empty((dim, dim))
    M = np.empty((dim, dim))
    vec = np.empty((6, max(dim, nc)))
    active = np.empty(dim, dtype=np.int64)
    is_active = np.empty(nc, dtype=np.bool_)
    Ginv[m, m] = 1.0
    penalty = 1.0
    for it in range(max_iter):
        tmax = merit(k, a0, al, tau0, T, inf, 0.0, R, a, tau, rho, theta)
        zero(H)
        for i in range(n):
            if not R[i]:
                finger_derivatives(0.0, i, lam[i], a, tau, rho, al, T, grads[i], H)
            if has_f:
                P[i] = force_derivatives(i, nu[i], a, tau, al, T, fgrads[i], H)
        big = 1e-8
        for j in range(m):
            big = max(big, abs(H[j, j]))
        # The Lagrangian Hessian is positive definite only on the tangent space of the active
        # angles; lam_i (g_i - g_mean)(g_i - g_mean)' is constant on the QP's manifold of
        # equal linearised angles, so adding it convexifies without moving the QP solution.
        for j in range(m):
            gmean[j] = 0.0
            for i in range(n):
                gmean[j] += lam[i] * grads[i, j]
        shift = 1e-9 * big
        ok = False
        for attempt in range(16):
            aug = 0.0 if attempt == 0 else big * 10.0 ** (attempt - 1)
            if attempt > 4:
                aug = big * 1e3
                shift *= 10.0
            for p in range(m):
                for q in range(m):
                    s = H[p, q]
                    for i in range(n):
                        s += aug * lam[i] * (grads[i, p] - gmean[p]) * (grads[i, q] - gmean[q])
                    Hs[p, q] = s
                Hs[p, p] += shift
            if cholesky_inverse(Hs, m, Hinv, Lc, Lic):
                ok = True
                break
        if not ok:
            return -1
        for p in range(m):
            for q in range(m):
                Ginv[p, q] = Hinv[p, q]
        row = 0
        for i in range(n):
            if R[i]:
                for cc in range(3):
                    for j in range(m):
                        C[row, j] = al[i, j] if cc == 0 else T[i, cc - 1, j]
                    C[row, m] = 0.0
                    b[row] = release - a[i] if cc == 0 else -tau[i, cc - 1]
                    row += 1
        for i in range(n):
            if not R[i]:
                for j in range(m):
                    C[row, j] = -grads[i, j]
                C[row, m] = 1.0
                b[row] = theta[i] - tmax
                row += 1
        for j in range(m):
            C[row, :] = 0.0
            C[row, j] = -1.0
            b[row] = k[j] - K
            row += 1
            C[row, :] = 0.0
            C[row, j] = 1.0
            b[row] = -K - k[j]
            row += 1
        if has_f:
            for i in range(n):
                for j in range(m):
                    C[row, j] = -fgrads[i, j]
                C[row, m] = 0.0
                b[row] = P[i] - f
                row += 1
        code = quadprog(Ginv, c, C, b, nc, meq, dim, x, u, GN, M, vec, active, is_active)
        if code != 0:
            return -10 - code
        total = 0.0
        row = meq
        for i in range(n):
            if not R[i]:
                total += u[row]
                row += 1
        if total <= 0.0:
            return -3
        row = meq
        for i in range(n):
            lam[i] = 0.0
            if not R[i]:
                lam[i] = u[row] / total
                row += 1
            if has_f:
                nu[i] = u[meq + (n - nr) + 2 * m + i] / total
        # predicted change of the merit
        model = -inf
        for i in range(n):
            if not R[i]:
                s = theta[i]
                for j in range(m):
                    s += grads[i, j] * x[j]
                model = max(model, s)
        now = tmax
        if has_f:
            for i in range(n):
                penalty = max(penalty, 2.0 * nu[i])
            for i in range(n):
                if P[i] > f:
                    now += penalty * (P[i] - f)
        pred = model - now
        if pred > -tol:
            return it
        alpha = 1.0
        accepted = False
        for _ in range(40):
            for j in range(m):
                k_try[j] = min(K, max(-K, k[j] + alpha * x[j]))
            value = merit(k_try, a0, al, tau0, T, f, penalty, R, a, tau, rho, theta)
            if value <= now + 1e-4 * alpha * pred:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            return it
        for j in range(m):
            k[j] = k_try[j]
    return max_iter


@_small
def read_multipliers(x, row, S, R, Q, lam, eta, nu):
    """Unpack lam (fingers in S), eta (released fingers, 3 each) and nu (force limits in Q)
    from x, starting at ``row``, in that order; the others are zero."""
    for i in range(S.shape[0]):
        lam[i] = 0.0
        if S[i]:
            lam[i] = x[row]
            row += 1
    for i in range(R.shape[0]):
        if R[i]:
            for c in range(3):
                eta[i, c] = x[row]
                row += 1
    for i in range(Q.shape[0]):
        nu[i] = 0.0
        if Q[i]:
            nu[i] = x[row]
            row += 1


@_jit
def polish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, release, max_iter, settle_by):
    """Newton's method on the KKT system of the minimax for fixed active sets; returns t.

    S: fingers with theta_i = t (multipliers lam, summing to 1); R: released fingers,
    P_i = release * n_i (the cone's apex, nudged inside; multipliers eta, 3 each, finger
    frame); Q: fingers at |P_i| = f (nu); fixed: -1/0/+1 per k_j for k_j = -K / free / +K.
    Returns -1 when the Newton matrix is singular or the iteration does not settle (within
    max_iter steps, or below SETTLED by step settle_by).
    """
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    grads = np.empty((n, m))
    fgrads = np.empty((n, m))
    P = np.empty(n)
    H = np.empty((m, m))
    A = np.empty((24, 24))
    rhs = np.empty(24)
    free = np.empty(m, dtype=np.int64)
    for j in range(m):
        if fixed[j] != 0:
            k[j] = fixed[j] * K
    nf = 0
    for j in range(m):
        if fixed[j] == 0:
            free[nf] = j
            nf += 1
    ns = 0
    nr = 0
    nq = 0
    for i in range(n):
        ns += S[i]
        nr += R[i]
        nq += Q[i]
    size = nf + ns + 3 * nr + nq + 1
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    t = -inf
    for i in range(n):
        if S[i]:
            t = max(t, theta[i])
    for it in range(max_iter):
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        zero(H)
        for i in range(n):
            if S[i]:
                finger_derivatives(1.0, i, lam[i], a, tau, rho, al, T, grads[i], H)
            if Q[i]:
                P[i] = force_derivatives(i, nu[i], a, tau, al, T, fgrads[i], H)
        big = 1e-12
        for j in range(m):
            big = max(big, abs(H[j, j]))
        if it > 0:
            # converged: the KKT residual is at rounding level (steps may not be, along
            # directions in which the optimum is not unique)
            resid = 0.0
            for i in range(n):
                if S[i]:
                    resid = max(resid, abs(theta[i] - t))
                if R[i]:
                    resid = max(resid, abs(a[i] - release), abs(tau[i, 0]), abs(tau[i, 1]))
                if Q[i]:
                    resid = max(resid, abs(P[i] - f))
            for p in range(nf):
                j = free[p]
                g = 0.0
                for i in range(n):
                    if S[i]:
                        g += lam[i] * grads[i, j]
                    if R[i]:
                        g += eta[i, 0] * al[i, j] + eta[i, 1] * T[i, 0, j] + eta[i, 2] * T[i, 1, j]
                    if Q[i]:
                        g += nu[i] * fgrads[i, j]
                resid = max(resid, abs(g))
            if resid <= 1e-14:
                return t
            if it >= settle_by and resid > SETTLED:
                return -1.0  # not in Newton's quadratic phase yet: the caller tries otherwise
        for p in range(size):
            for q in range(size):
                A[p, q] = 0.0
        for p in range(nf):
            for q in range(nf):
                A[p, q] = H[free[p], free[q]]
            A[p, p] += 1e-9 * big  # flat directions (non-unique optima) stay solvable
            rhs[p] = 0.0
        # Each multiplier row gets -reg (new - old multiplier): the fixed point is unchanged,
        # and multipliers the active constraints leave undetermined (more of them than free
        # directions, e.g. every k_j on the box) stay at their previous values.
        reg = 1e-12
        row = nf
        for i in range(n):
            if S[i]:
                for p in range(nf):
                    A[p, row] = grads[i, free[p]]
                    A[row, p] = grads[i, free[p]]
                A[row, size - 1] = -1.0
                A[size - 1, row] = 1.0
                A[row, row] = -reg
                rhs[row] = t - theta[i] - reg * lam[i]
                row += 1
        for i in range(n):
            if R[i]:
                for c in range(3):
                    for p in range(nf):
                        j = free[p]
                        v = al[i, j] if c == 0 else T[i, c - 1, j]
                        A[p, row] = v
                        A[row, p] = v
                    A[row, row] = -reg
                    if c == 0:
                        rhs[row] = release - a[i] - reg * eta[i, c]
                    else:
                        rhs[row] = -tau[i, c - 1] - reg * eta[i, c]
                    row += 1
        for i in range(n):
            if Q[i]:
                for p in range(nf):
                    A[p, row] = fgrads[i, free[p]]
                    A[row, p] = fgrads[i, free[p]]
                A[row, row] = -reg
                rhs[row] = f - P[i] - reg * nu[i]
                row += 1
        rhs[size - 1] = 1.0
        if not lu_solve(A, rhs, size):
            return -1.0
        step = 0.0
        for p in range(nf):
            k[free[p]] += rhs[p]
            step = max(step, abs(rhs[p]))
        t += rhs[size - 1]
        read_multipliers(rhs, nf, S, R, Q, lam, eta, nu)
        if step <= 1e-15 * (1.0 + K) and it > 0:
            return t
    return -1.0


@_small
def dual_vectors(al, T, S, R, Q, ct, st, lg, phi, z, u, w):
    """Smooth fingers' dual vectors at the angle (ct, st) into z; w = sum A_i' (z_i + u_i)."""
    n, m = al.shape
    for i in range(n):
        if S[i]:
            z[i, 0] = -lg[i] * st
            z[i, 1] = lg[i] * ct * cos(phi[i])
            z[i, 2] = lg[i] * ct * sin(phi[i])
    for j in range(m):
        s = 0.0
        for i in range(n):
            if S[i] or R[i]:
                s += z[i, 0] * al[i, j] + z[i, 1] * T[i, 0, j] + z[i, 2] * T[i, 1, j]
            if Q[i]:
                s += u[i, 0] * al[i, j] + u[i, 1] * T[i, 0, j] + u[i, 2] * T[i, 1, j]
        w[j] = s


@_jit
def certify(a0, al, tau0, T, K, f, k, t_low, S, R, Q, fixed, lam, eta, nu):
    """Evaluate the weak-duality certificate L(t_low) from the KKT multipliers at k.

    For any z_i in the polar cone of {P : theta(P) <= t} (z = l (cos t y b - sin t n),
    l >= 0, |y| <= 1) and any u_i: every k in the box with all theta_i <= t and
    |P_i| <= f satisfies sum z_i.P_i(k) + sum (u_i.P_i(k) - |u_i| f) <= 0, so
        L(t) = sum z_i.F_i + sum (u_i.F_i - |u_i| f) - K ||sum A_i' (z_i + u_i)||_1 > 0
    proves that no such k exists, i.e. the optimum is > t (>= t for L = 0).
    The KKT multipliers at the optimum t* give L(t*) = 0 only up to rounding, so the dual
    point is moved to t_low < t*: the cone directions rotate to t_low and minimum-norm
    corrections of (l_i, angle of y_i, eta_i, u_i) zero the free components of the L1 term
    again (Gauss-Newton: the angles enter non-linearly); what remains is about
    (t* - t_low) sum l_i |P_i| > 0, and the corrections cost only second-order terms
    (a dual direction off by d loses about |u_i| f d^2 / 2).
    Returns (L, box_share) where box_share is the box term's share of the certificate.
    """
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    ct, st = cos(t_low), sin(t_low)
    z = np.zeros((n, 3))  # dual vectors in the finger frames (normal, b, c)
    lg = np.zeros(n)
    phi = np.zeros(n)
    u = np.zeros((n, 3))  # force-limit duals nu_i P_i / |P_i|
    for i in range(n):
        Pn = sqrt(a[i] ** 2 + rho[i] ** 2)
        if S[i]:
            lg[i] = max(0.0, lam[i]) / Pn
            phi[i] = atan2(tau[i, 1], tau[i, 0])
        if Q[i]:
            scale_u = max(0.0, nu[i]) / Pn
            u[i, 0] = a[i] * scale_u
            u[i, 1] = tau[i, 0] * scale_u
            u[i, 2] = tau[i, 1] * scale_u
        if R[i]:
            for c in range(3):
                z[i, c] = eta[i, c]
    # A released finger whose dual lies on the polar cone's boundary (released and at the
    # maximum angle at once) is corrected like the smooth fingers, along that boundary, so
    # that the correction cannot push it out of the cone.
    Sm = S.copy()
    Rm = R.copy()
    cot = ct / max(st, 1e-300)
    for i in range(n):
        if R[i]:
            x0 = -z[i, 0]
            r = sqrt(z[i, 1] ** 2 + z[i, 2] ** 2)
            if x0 > 0.0 and r >= cot * x0 * (1.0 - 1e-6):
                Sm[i] = True
                Rm[i] = False
                lg[i] = x0 / st
                phi[i] = atan2(z[i, 2], z[i, 1])
    w = np.zeros(m)
    free = np.empty(m, dtype=np.int64)
    nf = 0
    for j in range(m):
        if fixed[j] == 0:
            free[nf] = j
            nf += 1
    ncols = 0
    for i in range(n):
        ncols += 2 * Sm[i] + 3 * Rm[i] + 3 * Q[i]
    J = np.zeros((m, 20))
    G = np.empty((m, m))
    y = np.empty(m)
    for _ in range(4 if nf > 0 and ncols > 0 else 0):
        # minimum-norm correction J dc = -w_free
        dual_vectors(al, T, Sm, Rm, Q, ct, st, lg, phi, z, u, w)
        col = 0
        for i in range(n):
            if Sm[i]:
                cp, sp = cos(phi[i]), sin(phi[i])
                for p in range(nf):
                    j = free[p]
                    J[p, col] = -st * al[i, j] + ct * (cp * T[i, 0, j] + sp * T[i, 1, j])
                    J[p, col + 1] = lg[i] * ct * (cp * T[i, 1, j] - sp * T[i, 0, j])
                col += 2
            for _twice in range(int(Rm[i]) + int(Q[i])):  # z_i of a released finger, then u_i
                for c in range(3):
                    for p in range(nf):
                        j = free[p]
                        J[p, col] = al[i, j] if c == 0 else T[i, c - 1, j]
                    col += 1
        big = 0.0
        residual = 0.0
        for p in range(nf):
            for q in range(nf):
                s = 0.0
                for c in range(ncols):
                    s += J[p, c] * J[q, c]
                G[p, q] = s
            big = max(big, G[p, p])
            y[p] = -w[free[p]]
            residual = max(residual, abs(y[p]))
        if residual == 0.0:
            break
        for p in range(nf):
            G[p, p] += 1e-12 * big
        if not lu_solve(G, y, nf):
            break
        col = 0
        for i in range(n):
            if Sm[i]:
                d_l = 0.0
                d_p = 0.0
                for p in range(nf):
                    d_l += J[p, col] * y[p]
                    d_p += J[p, col + 1] * y[p]
                lg[i] = max(0.0, lg[i] + d_l)
                phi[i] += d_p
                col += 2
            if Rm[i]:
                for c in range(3):
                    for p in range(nf):
                        z[i, c] += J[p, col] * y[p]
                    col += 1
            if Q[i]:
                for c in range(3):
                    for p in range(nf):
                        u[i, c] += J[p, col] * y[p]
                    col += 1
    # released fingers' duals must lie in the polar cone |z_b,c| <= cot(t) (-z_n)
    kappa = ct / max(st, 1e-300)
    for i in range(n):
        if Rm[i]:
            x0 = -z[i, 0]
            r = sqrt(z[i, 1] ** 2 + z[i, 2] ** 2)
            if r > kappa * x0:
                if kappa * r <= -x0:
                    z[i, 0] = 0.0
                    z[i, 1] = 0.0
                    z[i, 2] = 0.0
                else:  # nearest point of the boundary ray (1, kappa) in (-z_n, |z_bc|)
                    s = (x0 + kappa * r) / (1.0 + kappa * kappa)
                    z[i, 0] = -s
                    z[i, 1] *= kappa * s / r
                    z[i, 2] *= kappa * s / r
    dual_vectors(al, T, Sm, Rm, Q, ct, st, lg, phi, z, u, w)
    value = 0.0
    size = 0.0  # the terms' magnitudes, for the box share
    for i in range(n):
        if Sm[i] or Rm[i]:
            term = z[i, 0] * a0[i] + z[i, 1] * tau0[i, 0] + z[i, 2] * tau0[i, 1]
            value += term
            size += abs(term)
        if Q[i]:
            un = sqrt(u[i, 0] ** 2 + u[i, 1] ** 2 + u[i, 2] ** 2)
            term = u[i, 0] * a0[i] + u[i, 1] * tau0[i, 0] + u[i, 2] * tau0[i, 1] - un * f
            value += term
            size += abs(term)
    box = 0.0
    for j in range(m):
        box += K * abs(w[j])
    return value - box, box / max(size + box, 1e-300)


@_jit
def apex_start(a0, al, tau0, T, k):
    """k minimising sum_i |tau_i(k)|^2 (normal equations); False if they are singular."""
    n, m = al.shape
    M = np.zeros((m, m))
    r = np.zeros(m)
    for i in range(n):
        for c in range(2):
            for p in range(m):
                r[p] -= T[i, c, p] * tau0[i, c]
                for q in range(m):
                    M[p, q] += T[i, c, p] * T[i, c, q]
    ok = lu_solve(M, r, m)
    for j in range(m):
        k[j] = r[j] if ok else 0.0
    return ok


@_jit
def normal_start(a0, al, tau0, T, c, k):
    """k minimising sum_i |tau_i(k)|^2 + (a_i(k) - c)^2: every finger pushing with force c."""
    n, m = al.shape
    M = np.zeros((m, m))
    r = np.zeros(m)
    for i in range(n):
        for row in range(3):
            target = c - a0[i] if row == 0 else -tau0[i, row - 1]
            for p in range(m):
                vp = al[i, p] if row == 0 else T[i, row - 1, p]
                r[p] += vp * target
                for q in range(m):
                    M[p, q] += vp * (al[i, q] if row == 0 else T[i, row - 1, q])
    ok = lu_solve(M, r, m)
    for j in range(m):
        k[j] = r[j] if ok else 0.0
    return ok


@_jit
def move_force(a0, al, tau0, T, i, t0, t1, t2, k_from, k):
    """k = k_from moved (minimum norm) so that P_i = (t0, t1, t2) in finger i's frame."""
    m = al.shape[1]
    M = np.empty((3, 3))
    y = np.empty(3)
    for r in range(3):
        s = a0[i] if r == 0 else tau0[i, r - 1]
        for j in range(m):
            s += (al[i, j] if r == 0 else T[i, r - 1, j]) * k_from[j]
        y[r] = (t0 if r == 0 else (t1 if r == 1 else t2)) - s
        for c in range(3):
            s = 0.0
            for j in range(m):
                s += (al[i, j] if r == 0 else T[i, r - 1, j]) * (
                    al[i, j] if c == 0 else T[i, c - 1, j]
                )
            M[r, c] = s
    if not lu_solve(M, y, M.shape[0]):
        return False
    for j in range(m):
        k[j] = k_from[j] + y[0] * al[i, j] + y[1] * T[i, 0, j] + y[2] * T[i, 1, j]
    return True


@_small
def release_start(a0, al, tau0, T, K, i, release, k_from, k):
    """k = k_from moved (minimum norm) so that P_i = release * n_i; False if it leaves the box."""
    if not move_force(a0, al, tau0, T, i, release, 0.0, 0.0, k_from, k):
        return False
    for j in range(al.shape[1]):
        if abs(k[j]) > K:
            return False
    return True


@_jit
def polish_degenerate(a0, al, tau0, T, K, f, k, k_in, S, R, Q, fixed, lam, eta, nu):
    """:func:`polish` once more with one constraint fewer, where the sets hold more
    equations than there are unknowns (free k_j and t): at such a degenerate optimum
    (e.g. three equal angles and two fingers at the force limit, with three k_j free) one
    of them is weakly active, its multiplier zero, and dropping it leaves the same optimum
    a regular KKT point. Tries each candidate in turn from k_in; returns t, or -1."""
    n, m = al.shape
    count = 0
    unknowns = 1
    ns = 0
    for i in range(n):
        count += S[i] + 3 * R[i] + Q[i]
        ns += S[i]
    for j in range(m):
        unknowns += fixed[j] == 0
    if count <= unknowns:
        return -1.0
    lam0 = lam.copy()
    eta0 = eta.copy()
    nu0 = nu.copy()
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    for c in range(2 * n + m):
        if c < n:
            member = S[c] and ns > 1
        elif c < 2 * n:
            member = Q[c - n]
        else:
            member = fixed[c - 2 * n] != 0
        if not member:
            continue
        side = 0
        if c < n:
            S[c] = False
        elif c < 2 * n:
            Q[c - n] = False
        else:
            side = fixed[c - 2 * n]
            fixed[c - 2 * n] = 0
        copy_into(k, k_in, m)
        copy_into(lam, lam0, n)
        copy_into(nu, nu0, n)
        for i in range(n):
            for q in range(3):
                eta[i, q] = eta0[i, q]
        t = polish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, RELEASE, 12, 12)
        if t >= 0.0:
            # a KKT point of the original sets: multipliers >= 0, the dropped one holds
            evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
            ok = True
            for i in range(n):
                ok = ok and not (S[i] and lam[i] < -1e-12) and not (Q[i] and nu[i] < -1e-12)
            if c < n:
                ok = ok and theta[c] <= t + 1e-12
            elif c < 2 * n:
                ok = ok and sqrt(a[c - n] ** 2 + rho[c - n] ** 2) <= f * (1.0 + 1e-12)
            else:
                ok = ok and abs(k[c - 2 * n]) <= K * (1.0 + 1e-12)
            if ok:
                return t
        if c < n:
            S[c] = True
        elif c < 2 * n:
            Q[c - n] = True
        else:
            fixed[c - 2 * n] = side
    copy_into(k, k_in, m)
    copy_into(lam, lam0, n)
    copy_into(nu, nu0, n)
    return -1.0


@_jit
def finish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, settle_by):
    """Polish the KKT point for the given sets, repairing them, then certify it.

    settle_by: see :func:`polish` (12, its step limit, when k starts near the optimum).
    Returns (t_up, lower, box_share); lower < 0 when no certificate was found.
    """
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    grads = np.empty((n, m))
    fg = np.empty(m)
    Hd = np.zeros((m, m))
    k_in = k.copy()
    for _ in range(6):
        t = polish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, RELEASE, 12, settle_by)
        if t < 0.0:
            t = polish_degenerate(a0, al, tau0, T, K, f, k, k_in, S, R, Q, fixed, lam, eta, nu)
        if t < 0.0:
            for j in range(m):
                k[j] = k_in[j]
            return -1.0, -1.0, 0.0
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        changed = False
        # a free k_j beyond the box: fix it at the bound
        for j in range(m):
            if fixed[j] == 0 and abs(k[j]) > K:
                fixed[j] = 1 if k[j] > 0 else -1
                changed = True
        # a finger below t that the sets hold equal (negative multiplier): drop it
        worst = -1
        value = -1e-12
        for i in range(n):
            if S[i] and lam[i] < value:
                value = lam[i]
                worst = i
        if worst >= 0:
            S[worst] = False
            changed = True
        for i in range(n):
            if Q[i] and nu[i] < -1e-12:
                Q[i] = False
                changed = True
        # a fixed k_j whose multiplier pulls inwards: free it
        if not changed:
            g = np.zeros(m)
            for i in range(n):
                if S[i]:
                    finger_derivatives(1.0, i, 0.0, a, tau, rho, al, T, grads[i], Hd)
                    for j in range(m):
                        g[j] += lam[i] * grads[i, j]
                if R[i]:
                    for j in range(m):
                        g[j] += (
                            eta[i, 0] * al[i, j] + eta[i, 1] * T[i, 0, j] + eta[i, 2] * T[i, 1, j]
                        )
                if Q[i]:
                    force_derivatives(i, 0.0, a, tau, al, T, fg, Hd)
                    for j in range(m):
                        g[j] += nu[i] * fg[j]
            worst = -1
            value = -1e-12
            for j in range(m):
                if fixed[j] != 0:
                    mu = -fixed[j] * g[j]
                    if mu < value:
                        value = mu
                        worst = j
            if worst >= 0:
                fixed[worst] = 0
                changed = True
        # a finger outside the sets above t: add it
        for i in range(n):
            if not S[i] and not R[i] and theta[i] > t + 1e-12:
                S[i] = True
                changed = True
            if f < inf and not Q[i] and sqrt(a[i] ** 2 + rho[i] ** 2) > f * (1.0 + 1e-12):
                Q[i] = True
                changed = True
        if not changed:
            break
    else:
        return -1.0, -1.0, 0.0
    t_up = -1.0
    for i in range(n):
        if not R[i]:
            t_up = max(t_up, theta[i])
    for i in range(n):
        if R[i]:
            t_up = max(t_up, theta[i])
    if t_up >= pi / 2:
        # beyond 90 deg the cones are not convex and this certificate does not hold
        return t_up, -1.0, 0.0
    for delta in _DELTAS:
        t_low = t_up - delta
        if t_low <= 0.0:
            return t_up, 0.0, 0.0
        L, share = certify(a0, al, tau0, T, K, f, k, t_low, S, R, Q, fixed, lam, eta, nu)
        if L >= 0.0:
            return t_up, t_low, share
    return t_up, -1.0, 0.0


@_jit
def dual_value(a0, al, tau0, T, K, f, t, z, nuv, nus):
    """The certificate L(t) of :func:`certify` for explicit dual vectors (finger frames).

    z_i is first projected onto the polar cone of {theta <= t} and nuv_i onto the ball
    |nuv_i| <= nus_i, so the value is a valid bound whatever the input.
    """
    n, m = al.shape
    ct, st = cos(t), sin(t)
    zz = np.empty((n, 3))
    vv = np.empty((n, 3))
    for i in range(n):
        # polar cone of {|tau| <= tan(t) a}: |z_bc| <= cot(t) (-z_n), in coordinates
        # (x0, r) = (-z_n, |z_bc|) the cone r <= kappa x0 with kappa = cot t
        x0 = -z[i, 0]
        r = sqrt(z[i, 1] ** 2 + z[i, 2] ** 2)
        zz[i, 0], zz[i, 1], zz[i, 2] = z[i, 0], z[i, 1], z[i, 2]
        if r * st > ct * x0:
            if ct * r <= -st * x0:
                zz[i, 0] = zz[i, 1] = zz[i, 2] = 0.0
            else:
                # nearest point of the boundary ray (st, ct) of the (x0, r) plane
                s = x0 * st + r * ct
                zz[i, 0] = -s * st
                zz[i, 1] = z[i, 1] * (s * ct / r)
                zz[i, 2] = z[i, 2] * (s * ct / r)
        r = sqrt(nuv[i, 0] ** 2 + nuv[i, 1] ** 2 + nuv[i, 2] ** 2)
        shrink = 1.0 if r <= nus[i] else nus[i] / r
        for c in range(3):
            vv[i, c] = nuv[i, c] * shrink
    value = 0.0
    size = 0.0
    for i in range(n):
        term = zz[i, 0] * a0[i] + zz[i, 1] * tau0[i, 0] + zz[i, 2] * tau0[i, 1]
        if f < inf:
            term += vv[i, 0] * a0[i] + vv[i, 1] * tau0[i, 0] + vv[i, 2] * tau0[i, 1]
            term -= nus[i] * f
        value += term
        size += abs(term)
    box = 0.0
    for j in range(m):
        w = 0.0
        for i in range(n):
            w += zz[i, 0] * al[i, j] + zz[i, 1] * T[i, 0, j] + zz[i, 2] * T[i, 1, j]
            if f < inf:
                w += vv[i, 0] * al[i, j] + vv[i, 1] * T[i, 0, j] + vv[i, 2] * T[i, 1, j]
        box += K * abs(w)
    return value - box, box / max(size + box, 1e-300)


@_jit
def barrier_terms(x, a0, al, tau0, T, K, f, ct, st, wts, cones, g, H, tb, derivatives):
    """Value, gradient g and Hessian H of  tb * s + barrier  at x = (k, s); inf if outside.

    With derivatives = 0.0 only the value is computed (line searches).
    cones: 1.0 = the finger cones ct |tau_i| <= st a_i + wts_i s with the forces hard,
    0.0 = phase I, the force balls |P_i| <= f + s only. (Flags are floats: numba compiles
    a function once per literal integer or boolean it is called with.)
    """
    n, m = al.shape
    dim = m + 1
    s = x[m]
    val = tb * s
    if derivatives != 0.0:
        for p in range(dim):
            g[p] = 0.0
            for q in range(dim):
                H[p, q] = 0.0
        g[m] = tb
    for j in range(m):
        up, lo = K - x[j], K + x[j]
        if up <= 0.0 or lo <= 0.0:
            return inf
        val -= log(up) + log(lo)
        if derivatives == 0.0:
            continue
        g[j] += 1.0 / up - 1.0 / lo
        H[j, j] += 1.0 / (up * up) + 1.0 / (lo * lo)
    dsig = np.empty(dim)
    jv = np.empty((3, dim))
    v = np.empty(3)
    for i in range(n):
        a = a0[i]
        t0 = tau0[i, 0]
        t1 = tau0[i, 1]
        for j in range(m):
            a += al[i, j] * x[j]
            t0 += T[i, 0, j] * x[j]
            t1 += T[i, 1, j] * x[j]
        for kind in range(2):
            # kind 0: finger cone (when cones == 1); kind 1: force ball (if a limit is set)
            if kind == 0 and cones != 0.0:
                sig = st * a + wts[i] * s
                nv = 2
                v[0], v[1] = ct * t0, ct * t1
                for j in range(m):
                    dsig[j] = st * al[i, j]
                    jv[0, j] = ct * T[i, 0, j]
                    jv[1, j] = ct * T[i, 1, j]
                dsig[m] = wts[i]
                jv[0, m] = 0.0
                jv[1, m] = 0.0
            elif kind == 1 and f < inf:
                sig = f + (s if cones == 0.0 else 0.0)
                nv = 3
                v[0], v[1], v[2] = a, t0, t1
                for j in range(m):
                    dsig[j] = 0.0
                    jv[0, j] = al[i, j]
                    jv[1, j] = T[i, 0, j]
                    jv[2, j] = T[i, 1, j]
                dsig[m] = 1.0 if cones == 0.0 else 0.0
                jv[0, m] = 0.0
                jv[1, m] = 0.0
                jv[2, m] = 0.0
            else:
                continue
            vv = 0.0
            for c in range(nv):
                vv += v[c] * v[c]
            D = sig * sig - vv
            if sig <= 0.0 or D <= 0.0:
                return inf
            val -= log(D)
            if derivatives == 0.0:
                continue
            # grad(-log D) = -(2 sig dsig - 2 Jv' v) / D
            for p in range(dim):
                jtv = 0.0
                for c in range(nv):
                    jtv += jv[c, p] * v[c]
                gd = 2.0 * (sig * dsig[p] - jtv)
                g[p] -= gd / D
                for q in range(p + 1):
                    jtv_q = 0.0
                    jj = 0.0
                    for c in range(nv):
                        jtv_q += jv[c, q] * v[c]
                        jj += jv[c, p] * jv[c, q]
                    gq = 2.0 * (sig * dsig[q] - jtv_q)
                    h = 2.0 * (jj - dsig[p] * dsig[q]) / D + gd * gq / (D * D)
                    H[p, q] += h
                    if q != p:
                        H[q, p] += h
    return val


@_jit
def barrier_solve(a0, al, tau0, T, K, f, t, wts, cones, x, gap, stop_below, tb0):
    """Path-following log-barrier method for  min s  over the cone problem at a fixed t.

    x = (k, s) must be strictly feasible on entry; on exit it is the final iterate and the
    returned tb is the last barrier weight (duality gap about nu / tb). The weight starts
    at tb0 (large when x is a warm start near the optimum). Stops early once s < stop_below
    (phase I: a strictly feasible point is all that is needed).
    """
    n, m = al.shape
    dim = m + 1
    ct, st = cos(t), sin(t)
    g = np.empty(dim)
    H = np.empty((dim, dim))
    Hinv = np.empty((dim, dim))
    dx = np.empty(dim)
    xt = np.empty(dim)
    Lc = np.empty((dim, dim))
    Lic = np.empty((dim, dim))
    nu_b = 2.0 * m + 2.0 * n * (1 + (f < inf))
    tb = tb0
    for _ in range(60):
        for _ in range(50):
            val = barrier_terms(x, a0, al, tau0, T, K, f, ct, st, wts, cones, g, H, tb, 1.0)
            if not cholesky_inverse(H, dim, Hinv, Lc, Lic):
                for p in range(dim):
                    H[p, p] += 1e-12 * (1.0 + abs(H[p, p]))
                if not cholesky_inverse(H, dim, Hinv, Lc, Lic):
                    return tb
            dec = 0.0
            for p in range(dim):
                s = 0.0
                for q in range(dim):
                    s -= Hinv[p, q] * g[q]
                dx[p] = s
                dec -= s * g[p]
            # dec = lambda^2, the squared Newton decrement: centred enough at 1e-10 (or 1e-2
            # while the barrier weight is still growing)
            if dec < 1e-10 or (dec < 1e-2 and nu_b / tb > gap):
                break
            alpha = 1.0
            for _ in range(40):
                for p in range(dim):
                    xt[p] = x[p] + alpha * dx[p]
                vt = barrier_terms(xt, a0, al, tau0, T, K, f, ct, st, wts, cones, g, H, tb, 0.0)
                # in the quadratic region (lambda < 0.01) any feasible full step is taken:
                # the value's rounding there exceeds the predicted decrease
                if vt <= val - 0.25 * alpha * dec or (dec < 1e-4 and vt < inf):
                    break
                alpha *= 0.5
            else:
                break
            for p in range(dim):
                x[p] = xt[p]
            if x[m] < stop_below:
                return tb
        if nu_b / tb < gap:
            return tb
        tb *= 10.0
    return tb


@_jit
def barrier_duals(x, a0, al, tau0, T, K, f, t, wts, tb, z, nuv, nus):
    """Dual vectors of the centred barrier point x (phase II) for :func:`dual_value`.

    The barrier -log(sig^2 - |v|^2) of a cone |v| <= sig has the dual pair
    (2 sig, -2 v) / (tb (sig^2 - |v|^2)); in the finger frame that is
    z_i = (-l st, -ct l_v) for the finger cones and (nus, -l_v) for the force balls.
    """
    n, m = al.shape
    ct, st = cos(t), sin(t)
    s = x[m]
    for i in range(n):
        a = a0[i]
        t0 = tau0[i, 0]
        t1 = tau0[i, 1]
        for j in range(m):
            a += al[i, j] * x[j]
            t0 += T[i, 0, j] * x[j]
            t1 += T[i, 1, j] * x[j]
        sig = st * a + wts[i] * s
        v0, v1 = ct * t0, ct * t1
        D = sig * sig - v0 * v0 - v1 * v1
        lsig = 2.0 * sig / (tb * D)
        z[i, 0] = -lsig * st
        z[i, 1] = ct * 2.0 * v0 / (tb * D)
        z[i, 2] = ct * 2.0 * v1 / (tb * D)
        nus[i] = 0.0
        nuv[i, 0] = nuv[i, 1] = nuv[i, 2] = 0.0
        if f < inf:
            D = f * f - a * a - t0 * t0 - t1 * t1
            nus[i] = 2.0 * f / (tb * D)
            nuv[i, 0] = 2.0 * a / (tb * D)
            nuv[i, 1] = 2.0 * t0 / (tb * D)
            nuv[i, 2] = 2.0 * t1 / (tb * D)


@_jit
def force_certificate(a0, al, tau0, T, K, f, k):
    """Certificate that no k in the box has every |P_i| <= f, from the point k that
    minimises the largest excess max_i |P_i| - f: with weights nu_i >= 0 (sum 1) on the
    fingers at that maximum and v_i = P_i / |P_i|, every such k would satisfy
    sum nu_i (v_i . P_i(k) - f) <= 0, so
        L = sum nu_i (v_i . F_i - f) - K || sum nu_i A_i' v_i ||_1 > 0
    proves the limits infeasible. The nu_i are the least-squares stationarity multipliers."""
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    P = np.empty(n)
    worst = 0.0
    for i in range(n):
        P[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
        worst = max(worst, P[i])
    Q = np.zeros(n, dtype=np.bool_)
    fixed = np.zeros(m, dtype=np.int64)
    for i in range(n):
        Q[i] = P[i] >= worst - 1e-6 * f
    for j in range(m):
        fixed[j] = 1 if k[j] >= K * (1.0 - 1e-6) else (-1 if k[j] <= -K * (1.0 - 1e-6) else 0)
    # least-squares multipliers: the force gradients take the place of the angles'
    grads = np.zeros((n, m))
    Hd = np.zeros((m, m))
    for i in range(n):
        if Q[i]:
            force_derivatives(i, 0.0, a, tau, al, T, grads[i], Hd)
    nc = 0
    for i in range(n):
        nc += Q[i]
    A = np.zeros((nc + 1, nc + 1))
    b = np.zeros(nc + 1)
    p = 0
    for i in range(n):
        if Q[i]:
            q = 0
            for i2 in range(n):
                if Q[i2]:
                    s = 0.0
                    for j in range(m):
                        if fixed[j] == 0:
                            s += grads[i, j] * grads[i2, j]
                    A[p, q] = s
                    q += 1
            A[p, p] += 1e-12
            A[p, nc] = 1.0
            A[nc, p] = 1.0
            p += 1
    b[nc] = 1.0
    if not lu_solve(A, b, nc + 1):
        return -1.0
    value = 0.0
    w = np.zeros(m)
    p = 0
    for i in range(n):
        if Q[i]:
            nu = max(0.0, b[p])
            p += 1
            v0, v1, v2 = a[i] / P[i], tau[i, 0] / P[i], tau[i, 1] / P[i]
            value += nu * (v0 * a0[i] + v1 * tau0[i, 0] + v2 * tau0[i, 1] - f)
            for j in range(m):
                w[j] += nu * (v0 * al[i, j] + v1 * T[i, 0, j] + v2 * T[i, 1, j])
    for j in range(m):
        value -= K * abs(w[j])
    return value


@_jit
def fallback(a0, al, tau0, T, K, f, k, gap, centre):
    """Robust certified minimax: Dinkelbach iterations on t over the convex cone problem.

    At a fixed t < 90 deg, v(t) = min over (k, s) of s subject to ct |tau_i| <= st a_i + w_i s
    (box, force limits) is negative exactly when some k has every theta_i < t; each v(t) is
    solved by the barrier method. From above, t <- max_i theta_i(k_t) with the weights
    w_i = |P_i(k)| of the previous point (Crouzeix-Ferland-Schaible) converges
    superlinearly. Each barrier starts from the best point moved 1% towards a centre of the
    box and the force limits (a point on their boundary would leave Newton's method a
    Hessian too ill-conditioned to move). k (in/out) starts inside the box; centre
    (out) is that centre.
    Returns (t_up, lower, status, box_share); lower < 0 unless NOT_PUSHING is decided.
    """
    n, m = al.shape
    dim = m + 1
    x = np.empty(dim)
    wts = np.ones(n)
    z = np.empty((n, 3))
    nuv = np.empty((n, 3))
    nus = np.empty(n)
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    for j in range(m):
        centre[j] = 0.0  # inside the box and (when f is finite) the force limits
    inner = 1.0 - 1e-9
    for j in range(m):
        k[j] = min(K * inner, max(-K * inner, k[j]))
    if f < inf:
        # phase I: min s subject to |P_i| <= f + s, to a centred point
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        excess = -inf
        for i in range(n):
            excess = max(excess, sqrt(a[i] ** 2 + rho[i] ** 2) - f)
        for j in range(m):
            x[j] = k[j]
        x[m] = max(excess, 0.0) + f
        tb = barrier_solve(a0, al, tau0, T, K, f, 0.0, wts, 0.0, x, 1e-4 * f, -inf, 1.0 / f)
        if x[m] >= -1e-9 * f:
            # the limits may admit no k: converge, then certify (k: the least excess)
            barrier_solve(a0, al, tau0, T, K, f, 0.0, wts, 0.0, x, 1e-14 * f, -inf, tb)
            for j in range(m):
                k[j] = min(K * inner, max(-K * inner, x[j]))
            if x[m] >= 0.0:
                L = force_certificate(a0, al, tau0, T, K, f, k)
                return pi, (pi / 2 if L > 0.0 else 0.0), NOT_PUSHING, 0.0
        for j in range(m):
            centre[j] = x[j]
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        excess = -inf
        for i in range(n):
            excess = max(excess, sqrt(a[i] ** 2 + rho[i] ** 2) - f)
        if excess > -1e-9 * f:
            copy_into(k, centre, m)
    t_best = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    k_best = k.copy()
    if t_best >= pi / 2:
        # can every finger push? v(pi/2) < 0 iff some k has all a_i > 0; the barrier's
        # duals certify v(pi/2) > 0 once its gap is below v (tried as the gap closes: at a
        # tight gap rounding spoils them)
        for j in range(m):
            x[j] = 0.99 * k[j] + 0.01 * centre[j]
        s0 = -inf
        evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        for i in range(n):
            s0 = max(s0, -a[i])
        x[m] = s0 + 1.0
        tb = 1.0
        L = -1.0
        share = 0.0
        for tight in (1e-3, 1e-5, 1e-7, 1e-9, 1e-11, 1e-13):
            tb = barrier_solve(a0, al, tau0, T, K, f, pi / 2, wts, 1.0, x, tight, -inf, tb)
            if x[m] < 0.0:
                break
            barrier_duals(x, a0, al, tau0, T, K, f, pi / 2, wts, tb, z, nuv, nus)
            L, share = dual_value(a0, al, tau0, T, K, f, pi / 2, z, nuv, nus)
            if L > 0.0:
                break
        t_try = evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        if t_try < pi / 2:
            t_best = t_try
            copy_into(k_best, x, m)
        else:
            if t_try < t_best:
                t_best = t_try
                copy_into(k, x, m)
            return t_best, (pi / 2 if L > 0.0 else 0.0), NOT_PUSHING, share
    t = t_best
    for _ in range(40):
        evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
        big = 0.0
        for i in range(n):
            wts[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
            big = max(big, wts[i])
        ct, st = cos(t), sin(t)
        for j in range(m):
            x[j] = min(K * inner, max(-K * inner, 0.99 * k_best[j] + 0.01 * centre[j]))
        evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        s0 = -inf
        for i in range(n):
            wts[i] = max(wts[i], 1e-3 * big)
            s0 = max(s0, (ct * rho[i] - st * a[i]) / wts[i])
        x[m] = s0 + 1e-3
        barrier_solve(a0, al, tau0, T, K, f, t, wts, 1.0, x, gap, -inf, 1e3)
        t_new = evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        if t_new < t_best:
            t_best = t_new
            copy_into(k_best, x, m)
        if not (t_new < t - 0.1 * gap):
            break
        t = t_new
    copy_into(k, k_best, m)
    return t_best, -1.0, INTERIOR, 0.0


@_jit
def finish_from(a0, al, tau0, T, K, f, k, lam, eta, tol, angle_tol):
    """Read the active sets off a near-optimal point k (within ``tol``; the fingers at the
    maximum angle within ``angle_tol``), then :func:`finish`."""
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    S = np.zeros(n, dtype=np.bool_)
    R = np.zeros(n, dtype=np.bool_)
    Q = np.zeros(n, dtype=np.bool_)
    fixed = np.zeros(m, dtype=np.int64)
    zero(eta)
    nu = np.zeros(n)
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    big = 0.0
    for i in range(n):
        big = max(big, sqrt(a[i] ** 2 + rho[i] ** 2))
    t_up = -1.0
    for i in range(n):
        R[i] = sqrt(a[i] ** 2 + rho[i] ** 2) < min(10.0 * tol, 1e-5) * big
        if not R[i]:
            t_up = max(t_up, theta[i])
    for i in range(n):
        S[i] = not R[i] and theta[i] >= t_up - angle_tol
        if f < inf:
            Q[i] = sqrt(a[i] ** 2 + rho[i] ** 2) >= f * (1.0 - tol)
    for j in range(m):
        if k[j] >= K * (1.0 - tol):
            fixed[j] = 1
        elif k[j] <= -K * (1.0 - tol):
            fixed[j] = -1
    multiplier_estimate(a, tau, rho, al, T, S, R, Q, fixed, lam, eta, nu)
    return finish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, 12)


@_jit
def multiplier_estimate(a, tau, rho, al, T, S, R, Q, fixed, lam, eta, nu):
    """Least-squares KKT multipliers at a near-optimal point, to start Newton's method.

    Minimises |sum lam_i grad theta_i + sum A_i' eta_i + sum nu_i grad |P_i||^2 over the free
    k_j with sum lam_i = 1. Newton's method on the KKT system needs multipliers as good as
    its point: equal weights can be far off where a finger's force is small (its angle
    then has a large gradient and curvature)."""
    n, m = al.shape
    cols = np.zeros((m, 16))  # one column per unknown multiplier, free rows only
    Hd = np.zeros((m, m))
    g = np.empty(m)
    nc = 0
    for i in range(n):
        if S[i]:
            finger_derivatives(1.0, i, 0.0, a, tau, rho, al, T, g, Hd)
            for j in range(m):
                cols[j, nc] = g[j] if fixed[j] == 0 else 0.0
            nc += 1
    ns = nc
    for i in range(n):
        if R[i]:
            for c in range(3):
                for j in range(m):
                    v = al[i, j] if c == 0 else T[i, c - 1, j]
                    cols[j, nc] = v if fixed[j] == 0 else 0.0
                nc += 1
    for i in range(n):
        if Q[i]:
            force_derivatives(i, 0.0, a, tau, al, T, g, Hd)
            for j in range(m):
                cols[j, nc] = g[j] if fixed[j] == 0 else 0.0
            nc += 1
    if ns == 0:
        return
    # [C'C  e; e' 0] [x; mu] = [0; 1], e marking the lam entries (sum lam = 1)
    A = np.zeros((nc + 1, nc + 1))
    b = np.zeros(nc + 1)
    big = 0.0
    for p in range(nc):
        for q in range(nc):
            s = 0.0
            for j in range(m):
                s += cols[j, p] * cols[j, q]
            A[p, q] = s
        big = max(big, A[p, p])
    for p in range(nc):
        A[p, p] += 1e-12 * big + 1e-300
    for p in range(ns):
        A[p, nc] = 1.0
        A[nc, p] = 1.0
    b[nc] = 1.0
    if not lu_solve(A, b, nc + 1):
        return
    read_multipliers(b, 0, S, R, Q, lam, eta, nu)


@_small
def fold(state, k_best, k, t_up, low, status, path):
    """Fold one attempt into the best point and the best certificate so far.

    state = (t_best, lower, status, path); each attempt's certified bound is valid on its
    own, and only certified attempts' points are kept. Returns True once the gap is closed.
    """
    if low >= 0.0 and t_up < state[0]:
        state[0] = t_up
        copy_into(k_best, k, k.shape[0])
    if low > state[1]:
        state[1] = low
        state[2] = status
    done = state[0] - state[1] <= GAP_TOL
    if done and state[3] == UNCERTIFIED:
        state[3] = path
    return done


@_small
def sets_from_point(K, f, k, a, rho, Q, fixed):
    """The force-limit and box sets that a near-optimal point k touches (within 1e-6)."""
    for q in range(a.shape[0]):
        Q[q] = f < inf and sqrt(a[q] ** 2 + rho[q] ** 2) >= f * (1.0 - 1e-6)
    for j in range(k.shape[0]):
        k[j] = min(K, max(-K, k[j]))
        fixed[j] = 1 if k[j] >= K * (1.0 - 1e-6) else (-1 if k[j] <= -K * (1.0 - 1e-6) else 0)


@_inline
def try_releases(a0, al, tau0, T, K, f, k_sqp, state, k_best):
    """Four fingers: one of them may let go at the optimum (P_i = 0, the cone's apex),
    where theta_i is singular and the SQP stalls. Try releasing each finger, weakest first;
    where the release is almost but not quite optimal (released and at the maximum angle
    at once, its dual just outside the polar cone), give it the small force its dual asks
    for and solve with every finger active."""
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    lam = np.empty(n)
    nu = np.zeros(n)
    eta = np.zeros((n, 3))
    S = np.zeros(n, dtype=np.bool_)
    R = np.zeros(n, dtype=np.bool_)
    Q = np.zeros(n, dtype=np.bool_)
    fixed = np.zeros(m, dtype=np.int64)
    k = np.empty(m)
    k_rel = np.empty(m)
    evaluate(k_sqp, a0, al, tau0, T, a, tau, rho, theta)
    order = np.empty(n, dtype=np.int64)  # fingers by |P_i|, smallest first
    for q in range(n):
        order[q] = q
        size_q = a[q] ** 2 + rho[q] ** 2
        p = q
        while p > 0 and a[order[p - 1]] ** 2 + rho[order[p - 1]] ** 2 > size_q:
            order[p] = order[p - 1]
            p -= 1
        order[p] = q
    for attempt in range(n):
        i = order[attempt]
        for q in range(n):
            R[q] = q == i
            lam[q] = 1.0 / (n - 1) if q != i else 0.0
            nu[q] = 0.0
        if not release_start(a0, al, tau0, T, K, i, RELEASE, k_sqp, k):
            continue
        if sqp(a0, al, tau0, T, K, f, R, RELEASE, k, lam, nu, 60, 1e-8) < 0:
            continue
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, 1e-6)
        if fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 3):
            return
        if t_up < 0.0 or t_up >= pi / 2:
            continue
        copy_into(k_rel, k, m)
        evaluate(k_rel, a0, al, tau0, T, a, tau, rho, theta)
        typical = 0.0
        for q in range(n):
            typical += sqrt(a[q] ** 2 + rho[q] ** 2) / n
        er = sqrt(eta[i, 1] ** 2 + eta[i, 2] ** 2)
        y0 = eta[i, 1] / er if er > 0.0 else 1.0
        y1 = eta[i, 2] / er if er > 0.0 else 0.0
        ct, st = cos(t_up), sin(t_up)
        for eps in (1e-3, 1e-2):
            size = eps * typical
            move_force(a0, al, tau0, T, i, size * ct, size * st * y0, size * st * y1, k_rel, k)
            for q in range(n):
                S[q] = True
                R[q] = False
                lam[q] = 1.0 / n
            evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
            sets_from_point(K, f, k, a, rho, Q, fixed)
            t_up, low, share = finish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, 12)
            if fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 3):
                return


@_inline
def try_push(a0, al, tau0, T, K, f, k_sqp, state, k_best):
    """Four fingers: the SQP may stall where a finger's force vanishes without that being
    optimal; restart it with the weakest finger pushing along its normal."""
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    lam = np.empty(n)
    nu = np.zeros(n)
    eta = np.zeros((n, 3))
    R = np.zeros(n, dtype=np.bool_)
    k = np.empty(m)
    evaluate(k_sqp, a0, al, tau0, T, a, tau, rho, theta)
    typical = 0.0
    weakest = 0
    for q in range(n):
        size_q = sqrt(a[q] ** 2 + rho[q] ** 2)
        typical += size_q / n
        if size_q < sqrt(a[weakest] ** 2 + rho[weakest] ** 2):
            weakest = q
    for push in (1.0, 4.0):
        for q in range(n):
            lam[q] = 1.0 / n
            nu[q] = 0.0
        move_force(a0, al, tau0, T, weakest, push * typical, 0.0, 0.0, k_sqp, k)
        for j in range(m):
            k[j] = min(K, max(-K, k[j]))
        if sqp(a0, al, tau0, T, K, f, R, 0.0, k, lam, nu, 60, 1e-8) < 0:
            continue
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, 1e-6)
        if fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 4):
            return


@_jit
def certify_min_slack(a0, al, tau0, T, K, f, t, wts, x, tol):
    """The certificate L(t) (:func:`certify`) at x = (k, s), the minimiser of the cone
    problem v(t) = min s (see :func:`fallback`) with s > 0.

    Its sets are read off x (within ``tol``) and its multipliers are the least-squares
    stationarity multipliers there (sum l_i w_i = 1), so that certify's correction starts
    from the dual of v(t) and L(t) is about v(t) > 0: the barrier's own duals are spoilt by
    rounding (1 / slack) near the optimum, its primal point is not. Returns (L, box_share).
    """
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    k = x[:m].copy()
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    ct, st = cos(t), sin(t)
    S = np.zeros(n, dtype=np.bool_)
    R = np.zeros(n, dtype=np.bool_)
    Q = np.zeros(n, dtype=np.bool_)
    fixed = np.zeros(m, dtype=np.int64)
    P = np.empty(n)
    big = 0.0
    for i in range(n):
        P[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
        big = max(big, P[i])
    for i in range(n):
        # a finger at the cone's apex has a dual anywhere in the polar cone (3 unknowns)
        R[i] = P[i] < 1e-6 * big
        S[i] = not R[i] and (ct * rho[i] - st * a[i]) / wts[i] >= x[m] - tol
        Q[i] = f < inf and P[i] >= f * (1.0 - tol)
    for j in range(m):
        fixed[j] = 1 if k[j] >= K * (1.0 - tol) else (-1 if k[j] <= -K * (1.0 - tol) else 0)
    # columns: d(z_i . A_i)/d l_i for the cones, A_i for the apex fingers' z_i, v_i . A_i
    # for the force limits (free rows only)
    cols = np.zeros((m, 4 * n))
    nc = 0
    for i in range(n):
        if S[i]:
            u0 = tau[i, 0] / rho[i] if rho[i] > 0.0 else 1.0
            u1 = tau[i, 1] / rho[i] if rho[i] > 0.0 else 0.0
            for j in range(m):
                if fixed[j] == 0:
                    cols[j, nc] = -st * al[i, j] + ct * (u0 * T[i, 0, j] + u1 * T[i, 1, j])
            nc += 1
    ns = nc
    for i in range(n):
        if R[i]:
            for c in range(3):
                for j in range(m):
                    if fixed[j] == 0:
                        cols[j, nc] = al[i, j] if c == 0 else T[i, c - 1, j]
                nc += 1
    for i in range(n):
        if Q[i]:
            for j in range(m):
                if fixed[j] == 0:
                    cols[j, nc] = (a[i] * al[i, j] + tau[i, 0] * T[i, 0, j]) / P[i]
                    cols[j, nc] += tau[i, 1] * T[i, 1, j] / P[i]
            nc += 1
    if ns == 0:
        return -1.0, 0.0
    A = np.zeros((nc + 1, nc + 1))
    b = np.zeros(nc + 1)
    diag = 0.0
    for p in range(nc):
        for q in range(nc):
            v = 0.0
            for j in range(m):
                v += cols[j, p] * cols[j, q]
            A[p, q] = v
        diag = max(diag, A[p, p])
    for p in range(nc):
        A[p, p] += 1e-12 * diag + 1e-300
    c = 0
    for i in range(n):
        if S[i]:
            A[c, nc] = wts[i]
            A[nc, c] = wts[i]
            c += 1
    b[nc] = 1.0
    if not lu_solve(A, b, nc + 1):
        return -1.0, 0.0
    lam = np.zeros(n)
    nu = np.zeros(n)
    eta = np.zeros((n, 3))
    c = 0
    for i in range(n):
        if S[i]:
            lam[i] = b[c] * P[i]  # certify takes l_i = lam_i / |P_i|
            c += 1
    for i in range(n):
        if R[i]:
            for q in range(3):
                eta[i, q] = b[c]
                c += 1
    for i in range(n):
        if Q[i]:
            nu[i] = b[c]
            c += 1
    return certify(a0, al, tau0, T, K, f, k, t, S, R, Q, fixed, lam, eta, nu)


@_jit
def bisect(a0, al, tau0, T, K, f, k_best, centre, lo, hi):
    """Bisection on t over the cone problem v(t) (see :func:`fallback`), each step decided
    by the barrier's primal point (v(t) < 0: a better grip) or by a dual certificate
    (:func:`certify_min_slack`: no k reaches t). k_best (in/out) attains hi; each barrier
    starts from it moved 1% towards ``centre`` (see :func:`fallback`); returns the
    bracket (lo, hi, box_share). Steps aim just below hi first, where a near-optimal hi
    needs only one; a step that is decided neither way (rounding, at the last few 1e-10 rad)
    moves the next one down, so lo is always certified and hi always attained.
    """
    n, m = al.shape
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    wts = np.empty(n)
    x = np.empty(m + 1)
    share = 0.0
    top = hi  # the next t is below top (above it, steps are undecided or attained)
    inner = 1.0 - 1e-9
    for it in range(80):
        if hi - lo <= 0.5 * GAP_TOL or top <= lo:
            break
        t = max(0.5 * (lo + top), top - (2.0**it) * 1e-10)
        evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
        big = 0.0
        for i in range(n):
            wts[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
            big = max(big, wts[i])
        for i in range(n):
            wts[i] = max(wts[i], 1e-3 * big)
        for j in range(m):
            x[j] = min(K * inner, max(-K * inner, 0.99 * k_best[j] + 0.01 * centre[j]))
        evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        ct, st = cos(t), sin(t)
        s0 = -inf
        for i in range(n):
            s0 = max(s0, (ct * rho[i] - st * a[i]) / wts[i])
        x[m] = s0 + 1e-3
        tb = 1e3
        decided = False
        for tight in (1e-8, 1e-11, 1e-13):
            tb = barrier_solve(a0, al, tau0, T, K, f, t, wts, 1.0, x, tight, -inf, tb)
            if x[m] < 0.0:
                t_new = evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
                if t_new < hi:
                    hi = t_new
                    copy_into(k_best, x, m)
                top = min(top, hi)
                decided = True
                break
            for tol in (1e-9, 1e-11, 1e-7):
                L, box = certify_min_slack(a0, al, tau0, T, K, f, t, wts, x, tol)
                if L > 0.0:
                    lo = t
                    share = box
                    decided = True
                    break
            if decided:
                break
        if not decided:
            top = t
    return lo, hi, share


@_inline
def try_fallback(a0, al, tau0, T, K, f, k_start, state, k_best):
    """The robust primal of :func:`fallback`, then the KKT certificate, then bisection."""
    n = al.shape[0]
    k = k_start.copy()
    lam = np.full(n, 1.0 / n)
    eta = np.zeros((n, 3))
    centre = np.empty(k.shape[0])
    t_up, low, status, share = fallback(a0, al, tau0, T, K, f, k, 1e-11, centre)
    if fold(state, k_best, k, t_up, max(low, 0.0), status, 5) or status == NOT_PUSHING:
        return
    k_fallback = k.copy()
    for tol in (1e-6, 1e-5, 1e-4, 1e-3):
        # the barrier's point is near-optimal to about 1e-8; degenerate optima (a finger
        # with almost no force) need looser tolerances to read the active sets off it
        copy_into(k, k_fallback, k.shape[0])
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, tol, tol)
        if fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 5):
            return
    # the certified bisection, from the best point so far and the best bound
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    copy_into(k, k_fallback, k.shape[0])
    t_up = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    if state[0] < t_up:
        copy_into(k, k_best, k.shape[0])
        t_up = state[0]
    lo, hi, share = bisect(a0, al, tau0, T, K, f, k, centre, max(state[1], 0.0), t_up)
    fold(state, k_best, k, hi, lo, BOUNDARY if share > 1e-9 else INTERIOR, 8)


@_inline
def solve_one(F, E, N, K_in, f_in, k, theta, k_near, near):
    """Certified minimax for one grasp; fills k and theta, returns (lower, status, path).

    near: k_near (newtons) is the optimum of a nearby grasp (the previous pose of a
    trajectory): Newton's method starts there, with the sets it nearly has, first.
    path (diagnostic): 0 apex, 1 direct Newton, 2 SQP, 3 released finger, 4 SQP restarted,
    5 fallback, 6 not certified to GAP_TOL, 7 from the nearby optimum, 8 bisection;
    -1 (INVALID) if an input is NaN or inf, or a BAD_* code for an input refused.
    """
    n = F.shape[0]
    m = E.shape[0]
    for j in range(m):
        k[j] = 0.0
    for i in range(n):
        theta[i] = 0.0
    if not (all_finite(F) and all_finite(E) and all_finite(N)):
        return 0.0, INTERIOR, INVALID
    a0 = np.empty(n)
    al = np.empty((n, m))
    tau0 = np.empty((n, 2))
    T = np.empty((n, 2, m))
    scale, code = setup(F, E, N, a0, al, tau0, T)
    if code != 0:
        return 0.0, INTERIOR, code
    if scale == 0.0:
        # no load: k = 0 holds it with no force at all (every angle 0, the least possible)
        return 0.0, INTERIOR, APEX
    if not LOAD_RANGE[0] <= scale <= LOAD_RANGE[1]:
        return 0.0, INTERIOR, BAD_LOAD
    # the rest works in units of the load: the friction angles do not depend on its scale
    K = K_in / scale
    f = f_in / scale
    if not RATIO_RANGE[0] <= K <= RATIO_RANGE[1]:
        return 0.0, INTERIOR, BAD_K_MAX
    if f < inf and not RATIO_RANGE[0] <= f <= RATIO_RANGE[1]:
        return 0.0, INTERIOR, BAD_F_MAX
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    lam = np.full(n, 1.0 / n)
    nu = np.zeros(n)
    eta = np.zeros((n, 3))
    R = np.zeros(n, dtype=np.bool_)
    S = np.ones(n, dtype=np.bool_)
    Q = np.zeros(n, dtype=np.bool_)
    fixed = np.zeros(m, dtype=np.int64)
    state = np.array([inf, 0.0, INTERIOR, UNCERTIFIED])
    k_best = np.empty(m)
    done = False
    if near:
        # a step along a trajectory moves the optimum a little and its sets rarely: the
        # fingers within NEAR_ANGLES of the largest angle there are taken as the maximum
        for j in range(m):
            k[j] = min(K, max(-K, k_near[j] / scale))
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, NEAR_ANGLES)
        done = fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 7)
        if not done:  # start afresh (finish_from set lam and eta; its nu is its own)
            zero(eta)
            for i in range(n):
                lam[i] = 1.0 / n
    k_start = k_best  # (unused when the nearby optimum is certified)
    if not done:
        # start: the k that minimises the tangential forces (exact when they can all vanish)
        apex_start(a0, al, tau0, T, k)
        for j in range(m):
            k[j] = min(K, max(-K, k[j]))
        t_up = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        if n == 4 and f == inf:
            # four fingers: also try every finger pushing with a common normal force; the best
            # start saves the SQP about a quarter of its steps
            k_try = np.empty(m)
            for c in (1.0, 2.0, 4.0):
                normal_start(a0, al, tau0, T, c, k_try)
                for j in range(m):
                    k_try[j] = min(K, max(-K, k_try[j]))
                t_try = evaluate(k_try, a0, al, tau0, T, a, tau, rho, theta)
                if t_try < t_up:
                    t_up = t_try
                    copy_into(k, k_try, m)
            t_up = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        feasible = True
        for i in range(n):
            feasible = feasible and sqrt(a[i] ** 2 + rho[i] ** 2) <= f
        k_start = k.copy()
        if state[0] == inf or (feasible and t_up < state[0]):
            copy_into(k_best, k, m)  # the best point so far (fold keeps certified ones only)
            if feasible:
                state[0] = t_up
        if feasible and t_up <= GAP_TOL:
            state[3] = APEX  # every finger along its normal: 0 is attained, 0 is the bound
            done = True
    if not done and n == 3 and f == inf:
        # Newton on the KKT system straight from the start with every finger at the maximum
        # (the typical optimum): cheap, and certified like any other attempt; given up
        # early where Newton is not converging (then the SQP costs less than finishing)
        for j in range(m):
            fixed[j] = 1 if k[j] >= K else (-1 if k[j] <= -K else 0)
        t_up, low, share = finish(a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, 5)
        done = fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 1)
    k_sqp = k_start.copy()
    if not done:
        for i in range(n):
            lam[i] = 1.0 / n
        steps = sqp(a0, al, tau0, T, K, f, R, 0.0, k_sqp, lam, nu, 60, 1e-8)
        if steps >= 0 or n == 4:
            copy_into(k, k_sqp, m)
            t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, 1e-6)
            done = fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 2)
        if not done and steps >= 0:
            # not certified from a point 1e-8 from optimal: converge further, read sets again
            steps = sqp(a0, al, tau0, T, K, f, R, 0.0, k_sqp, lam, nu, 60, 1e-14)
            if steps >= 0:
                copy_into(k, k_sqp, m)
                t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, 1e-6)
                done = fold(state, k_best, k, t_up, low, BOUNDARY if share > 1e-9 else INTERIOR, 2)
    if not done and n == 4:
        try_releases(a0, al, tau0, T, K, f, k_sqp, state, k_best)
        done = state[0] - state[1] <= GAP_TOL
    if not done and n == 4:
        try_push(a0, al, tau0, T, K, f, k_sqp, state, k_best)
        done = state[0] - state[1] <= GAP_TOL
    if not done:
        try_fallback(a0, al, tau0, T, K, f, k_start, state, k_best)
    for j in range(m):
        k[j] = k_best[j] * scale
    t_best = evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
    status = int(state[2])
    excess = False
    for i in range(n):
        excess = excess or sqrt(a[i] ** 2 + rho[i] ** 2) > f * (1.0 + 1e-9)
    if t_best >= pi / 2 or excess:
        # no k keeps every finger pushing (or meets the force limits; k then exceeds them
        # least): certified when lower == pi / 2
        status = NOT_PUSHING
    return state[1], status, int(state[3])


@_entry
def solve_batch(F, E, N, K, f, k, theta, lower, status, path, follows, start, stop):
    """:func:`solve_one` for grasps start..stop of a flat batch (B, ...); releases the GIL.

    follows[b]: grasp b is near grasp b - 1 (the next pose of a trajectory), whose optimum
    (if solved in this call and not NOT_PUSHING) is its first start.
    """
    for b in range(start, stop):
        near = follows[b] and b > start and path[b - 1] >= 0 and status[b - 1] != NOT_PUSHING
        lower[b], status[b], path[b] = solve_one(
            F[b], E[b], N[b], K[b], f[b], k[b], theta[b], k[b - 1 if b > 0 else 0], near
        )
