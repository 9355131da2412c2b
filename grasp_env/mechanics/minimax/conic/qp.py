"""The active-set attempt's QP: Goldfarb and Idnani's dual active-set method with its
factorisation updated as rows enter and leave (docs/solver.md, "Any number of contacts",
"The active-set method").

The method and its choices are those of ``minimax.sqp.quadprog`` (the three- and four-finger
QP, which recomputes its projections from the active set at every inner step and stays as it
is): the same entering row (an equality first, else the most violated row, scaled by its
norm), the same step lengths and the same dropping rule, so the same iterates up to rounding.
What differs is the arithmetic of an inner step. With N the active rows (q of them), quadprog
forms G^-1 N' (q dim^2), N G^-1 N' (q^2 dim) and an LU factorisation (q^3 / 3) at every inner
step. Here, for the entering row c_p,

    y = G^-1 c_p          (dim^2, once for each entering row),
    s = N y               (q dim, once; an entry removed where a row is dropped),
    r = (N G^-1 N')^-1 s  (two triangular solves with its Cholesky factor L, 2 q^2),
    z = y - (G^-1 N') r   (q dim: the columns G^-1 n_a are kept, one added per row),

and the factor grows by one row where c_p enters, whose diagonal is sqrt(c_p . z) (the Schur
complement c_p' G^-1 c_p - s' M^-1 s, positive because c_p enters only where c_p . z > 0);
only a dropped row re-factorises (q^3 / 6). At the sizes of five to eight contacts (dim = 3n -
5, up to 19) that is several times fewer flops a QP.
"""

from __future__ import annotations

from math import inf, sqrt

from .codes import kernel


@kernel
def refactor(M, L, q):
    """L <- the lower Cholesky factor of the leading q x q block of M. False where a pivot
    is not positive (the active rows numerically dependent)."""
    for i in range(q):
        for j in range(i + 1):
            s = M[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 0.0:
                    return False
                L[i, i] = sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@kernel
def dual_qp(
    Ginv, c, C, b, nc, meq, first_pair, pairs, warm, dim, x, u, GN, M, L, vec, active, is_active
):
    """min 1/2 x'Gx + c'x subject to C x >= b (the first ``meq`` rows equalities C x = b,
    whose rows may be negated in place), by the dual active-set method of Goldfarb and
    Idnani with an updated Cholesky factor of N G^-1 N' (the module's doc).

    Rows first_pair + 2 j and first_pair + 2 j + 1 (j < pairs) are each other's negatives
    (the box's two sides, -b_j . d >= ... and b_j . d >= ...): their norm and their product
    with x are computed once for both.

    A warm start: the first ``warm`` entries of ``active`` (rows, increasing) are a guess of
    the active set (the previous SQP step's). The equality-constrained minimiser on those
    rows (those independent of the rows before them) is a state of the dual method where
    its multipliers on the inequalities are >= 0, and the method goes on from there (adding
    the rows it violates, dropping as it must); where one is negative it starts cold (x the
    unconstrained minimiser, no row active). Either way the solution is the QP's (unique:
    G is positive definite), and where the guess is right no row is searched for.

    ``Ginv`` is G^-1 (G positive definite). Fills x and the multipliers u (nc). Scratch: GN,
    M, L (dim, dim) (the columns G^-1 n_a, N G^-1 N' and its factor), vec (7, >= max(dim,
    nc)), active (dim), is_active (nc). Returns 0, or a positive code as quadprog does: 1
    where the active rows' projection is singular, 2 where the constraints are infeasible,
    3 or 4 where an iteration limit is hit."""
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
    sv = vec[6]
    for i in range(nc):
        is_active[i] = False
        sign[i] = 1.0
    q = 0
    last_pair = first_pair + 2 * pairs
    for i in range(nc):
        if first_pair < i < last_pair and (i - first_pair) % 2 == 1:
            cnorm[i] = cnorm[i - 1]
            continue
        s = 0.0
        for j in range(dim):
            s += C[i, j] * C[i, j]
        cnorm[i] = sqrt(s)
    if warm > 0:
        # the guess's rows enter one by one, as in an inner step: y = G^-1 c_p, its
        # products with the rows before it, the factor's new row (a row dependent on the
        # rows before it is left out)
        for k_ in range(warm):
            p = active[k_]
            for i in range(dim):
                s = 0.0
                for j in range(dim):
                    s += Ginv[i, j] * C[p, j]
                y[i] = s
            for a_ in range(q):
                s = 0.0
                for j in range(dim):
                    s += C[active[a_], j] * y[j]
                sv[a_] = s
            for a_ in range(q):
                s = sv[a_]
                for b_ in range(a_):
                    s -= L[a_, b_] * r[b_]
                r[a_] = s / L[a_, a_]
            s = 0.0
            for j in range(dim):
                s += C[p, j] * y[j]
            pivot = s
            for a_ in range(q):
                pivot -= r[a_] * r[a_]
            if q >= dim or not pivot > 1e-12 * s:
                continue
            for i in range(dim):
                GN[i, q] = y[i]
            for a_ in range(q):
                M[a_, q] = sv[a_]
                M[q, a_] = sv[a_]
                L[q, a_] = r[a_]
            M[q, q] = s
            L[q, q] = sqrt(pivot)
            active[q] = p
            q += 1
        # the multipliers on those rows as equalities: M ua = b_A - C_A x (x unconstrained)
        for a_ in range(q):
            s = b[active[a_]]
            for j in range(dim):
                s -= C[active[a_], j] * x[j]
            ua[a_] = s
        for a_ in range(q):
            s = ua[a_]
            for b_ in range(a_):
                s -= L[a_, b_] * ua[b_]
            ua[a_] = s / L[a_, a_]
        for a_ in range(q - 1, -1, -1):
            s = ua[a_]
            for b_ in range(a_ + 1, q):
                s -= L[b_, a_] * ua[b_]
            ua[a_] = s / L[a_, a_]
        feasible = True
        for a_ in range(q):
            feasible = feasible and (active[a_] < meq or ua[a_] >= 0.0)
        if feasible:
            for i in range(dim):
                s = x[i]
                for a_ in range(q):
                    s += GN[i, a_] * ua[a_]
                x[i] = s
            for a_ in range(q):
                is_active[active[a_]] = True
        else:
            q = 0
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
        dot = 0.0  # C_i . x of the first row of a pair, for its second
        for i in range(nc if p < 0 else 0):
            paired = first_pair <= i < last_pair
            if paired and (i - first_pair) % 2 == 1:
                dot = -dot
            elif paired or not is_active[i]:
                dot = 0.0
                for j in range(dim):
                    dot += C[i, j] * x[j]
            if not is_active[i]:
                s = (dot - b[i]) / cnorm[i]
                if s < worst - 1e-13 * (1.0 + abs(b[i]) / cnorm[i]):
                    worst = s
                    p = i
        if p < 0:
            for a_ in range(q):
                u[active[a_]] = ua[a_] * sign[active[a_]]
            return 0
        # the entering row's projections, once: y = G^-1 c_p, sv = N y
        for i in range(dim):
            s = 0.0
            for j in range(dim):
                s += Ginv[i, j] * C[p, j]
            y[i] = s
        for a_ in range(q):
            s = 0.0
            for j in range(dim):
                s += C[active[a_], j] * y[j]
            sv[a_] = s
        up = 0.0
        for _inner in range(2 * dim + 2):
            # r = M^-1 sv by L (forward: r holds L^-1 sv, the new factor row if p enters)
            for a_ in range(q):
                s = sv[a_]
                for b_ in range(a_):
                    s -= L[a_, b_] * r[b_]
                r[a_] = s / L[a_, a_]
            if q < dim:
                for a_ in range(q):
                    L[q, a_] = r[a_]  # (the row below the factor: kept only if p enters)
            for a_ in range(q - 1, -1, -1):
                s = r[a_]
                for b_ in range(a_ + 1, q):
                    s -= L[b_, a_] * r[b_]
                r[a_] = s / L[a_, a_]
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
                # p enters: its column G^-1 c_p, its row and column of M, the factor's row
                for i in range(dim):
                    GN[i, q] = y[i]
                for a_ in range(q):
                    M[a_, q] = sv[a_]
                    M[q, a_] = sv[a_]
                s = 0.0
                for j in range(dim):
                    s += C[p, j] * y[j]
                M[q, q] = s
                L[q, q] = sqrt(zn)
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
                sv[a_] = sv[a_ + 1]
                for i in range(dim):
                    GN[i, a_] = GN[i, a_ + 1]
            for a_ in range(kd, q - 1):
                for b_ in range(q):
                    M[a_, b_] = M[a_ + 1, b_]
            for b_ in range(kd, q - 1):
                for a_ in range(q - 1):
                    M[a_, b_] = M[a_, b_ + 1]
            q -= 1
            if not refactor(M, L, q):
                return 1
        else:
            return 3
    return 4
