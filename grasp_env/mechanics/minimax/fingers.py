"""The problem in the fingers' frames, the friction angles and their derivatives.

One problem: n <= 4 fingers, m = n (n - 1) / 2 <= 6 interaction scalars. Each finger is
written in its own frame (inward normal n_i, tangential basis b_i, c_i): with the forces
divided by ``scale`` (the largest equilibrating force),

    a_i(k) = a0_i + al_i . k          normal component n_i . P_i
    tau_i(k) = tau0_i + T_i k         tangential components (b_i . P_i, c_i . P_i)
    theta_i = atan2(|tau_i|, a_i)     paper eq. 2

and |P_i| = sqrt(a_i^2 + |tau_i|^2). Every routine works on these arrays.
"""

from __future__ import annotations

from math import atan, atan2, sqrt

from .codes import BAD_NORMAL, UNIT_TOL
from .jit import inline, kernel
from .linalg import stack_empty


@inline
def angle_arrays(n):
    """Arrays for :func:`evaluate`'s outputs (a, tau, rho, theta) of n fingers, in the stack
    frame of the kernel this is inlined into (see :func:`~.linalg.stack_empty`)."""
    return stack_empty(n), stack_empty((n, 2)), stack_empty(n), stack_empty(n)


@kernel
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


@inline
def angle(tangential, normal):
    """atan2(tangential, normal) for tangential >= 0; atan where it agrees (twice as fast)."""
    if normal > 0.0:
        return atan(tangential / normal)
    return atan2(tangential, normal)


@kernel
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


@kernel
def finger_derivatives(exact, i, w, a, tau, rho, al, T, grad, H):
    """The gradient of theta_i(k) (paper eq. 2) into grad, and w x its Hessian added to H.

    With exact False only the convex, circumferential part of the Hessian is added (the
    curvature of the cone |tau| <= tan(t) a), a positive semidefinite stand-in that the SQP
    uses far from the optimum; exact True gives the true Hessian for Newton's method.
    """
    m = al.shape[1]
    ai, ri = a[i], rho[i]
    if ri > 0.0:
        u0, u1 = tau[i, 0] / ri, tau[i, 1] / ri
    else:
        u0, u1 = 1.0, 0.0
    r2 = ri * ri + ai * ai
    gr = stack_empty(m)  # the gradient of |tau_i| (tau_i's along its direction u)
    for j in range(m):
        gr[j] = T[i, 0, j] * u0 + T[i, 1, j] * u1
        grad[j] = (ai * gr[j] - ri * al[i, j]) / r2
    if w == 0.0:
        return
    gv = stack_empty(m)  # tau_i's across u
    for j in range(m):
        gv[j] = T[i, 1, j] * u0 - T[i, 0, j] * u1
    c1 = w * (ai if exact else abs(ai)) / (r2 * max(ri, 1e-300))
    c2 = w * (ri * ri - ai * ai) / (r2 * r2) if exact else 0.0
    c3 = w * 2.0 * ai * ri / (r2 * r2) if exact else 0.0
    for p in range(m):
        for q in range(m):
            H[p, q] += (
                c1 * gv[p] * gv[q]
                + c2 * (gr[p] * al[i, q] + al[i, p] * gr[q])
                + c3 * (al[i, p] * al[i, q] - gr[p] * gr[q])
            )


@kernel
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


@inline
def apex_columns(al, T, R, fixed, cols, nc):
    """The columns A_i = (al_i, T_i) of the fingers at their cone's apex (R), three each, into
    cols from column nc, on the free k_j only (``fixed`` 0; cols is zero elsewhere); returns
    the next column."""
    for i in range(R.shape[0]):
        if R[i]:
            for c in range(3):
                for j in range(al.shape[1]):
                    if fixed[j] == 0:
                        cols[j, nc] = al[i, j] if c == 0 else T[i, c - 1, j]
                nc += 1
    return nc
