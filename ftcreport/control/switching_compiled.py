r"""Compiled (numba) switching bank: the filters (3.42), the model costs J_k (3.39-3.48) and the rule.

Face: :mod:`ftcreport.control.switching`.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import TIE_RTOL, _clip, _mv, _solve2, _tri
from ..model.compiled import bbar_rate, reduced, rotor_mass


@jit
def switching_rates(Lw, MB, u, g, eta, xc, dx):
    r"""The model bank's filters (3.42) and cost integrals, by superposition, into dx.

    The filters are linear in sigma_(k), so every model's estimate is that of the healthy model
    minus one filter per wheel: ``etahat_(k) = h - sum_j f_kj z_j``, f_k = 1 - sigma_(k) (the failure
    indicator), with h(0) = eta(0), z_j(0) = 0 and the applied (saturated) torque u::

        h'   = -gamma h + gamma eta + g + MB u
        z_j' = -gamma z_j + MB[:, j] u_j

    so the error (3.43) is ``etatilde_(k) = eta - etahat_(k) = A (1, f_k)`` with A = [eta - h, z_1 .. z_2n]
    (2 x (2n + 1)).  The integral cost of every model follows from one symmetric matrix,
    ``int_(k) = (1, f_k)^T M (1, f_k)``, ``M' = -forgetting M + A^T A`` (Narendra & Balakrishnan 1994;
    control/switching.py).  Both are linear ODEs, so RK4 integrates them exactly as it would the
    per-model states (equal to round-off).  State layout: ``xc[hat0 : hat0 + 2]`` = h, then z_j
    (2 each, wheel order 1r, 1l, 2r, ...); ``xc[int0 : int0 + n_int]`` = M's upper triangle row by row
    (``_tri``), present when c_int > 0.
    """
    nw = u.shape[0]
    u_app = u if math.isnan(Lw.u_limit) else _clip(u, -Lw.u_limit, Lw.u_limit)
    gm = Lw.gamma
    i0 = Lw.hat0
    d0 = 0.0
    d1 = 0.0
    for j in range(nw):
        # z_j' = -gamma z_j + MB[:, j] u_j
        dx[i0 + 2 + 2 * j] = -gm * xc[i0 + 2 + 2 * j] + MB[0, j] * u_app[j]
        dx[i0 + 3 + 2 * j] = -gm * xc[i0 + 3 + 2 * j] + MB[1, j] * u_app[j]
        d0 += u_app[j] * MB[0, j]
        d1 += u_app[j] * MB[1, j]
    # h' = -gamma h + gamma eta + g + MB u   (3.42) for sigma = 1
    dx[i0] = -gm * xc[i0] + gm * eta[0] + g[0] + d0
    dx[i0 + 1] = -gm * xc[i0 + 1] + gm * eta[1] + g[1] + d1
    if Lw.n_int > 0:
        D = nw + 1
        A = np.empty((2, D))
        A[0, 0] = eta[0] - xc[i0]
        A[1, 0] = eta[1] - xc[i0 + 1]
        for j in range(nw):
            A[0, j + 1] = xc[i0 + 2 + 2 * j]
            A[1, j + 1] = xc[i0 + 3 + 2 * j]
        for a in range(D):
            for b in range(a, D):
                m = Lw.int0 + _tri(a, b, D)
                # M' = -forgetting M + A^T A
                dx[m] = -Lw.forgetting * xc[m] + (A[0, a] * A[0, b] + A[1, a] * A[1, b])


@jit
def _model_cost(Lw, xc, e10, e11, s):
    r"""J_(k) = c_inst |etatilde_(k)|^2 + c_int int_(k) of one pattern ``s`` (3.46), from the superposed states.

    etatilde_(k) = (eta - h) + sum_j f_j z_j and int_(k) = M_00 + sum_j f_j (2 c_j + f_j M_jj),
    c_j = M_0j + sum_(i<j) f_i M_ij, f = 1 - s, summed in wheel order, skipping f_j = 0: for a 0/1
    pattern the same operations, in the same order, as the walk (``_walk``), so both give the same bits.
    """
    nw = s.shape[0]
    i0 = Lw.hat0
    e0 = e10
    e1 = e11
    for j in range(nw):
        f = 1.0 - s[j]
        if f != 0.0:
            # etatilde += f_j z_j
            e0 += f * xc[i0 + 2 + 2 * j]
            e1 += f * xc[i0 + 3 + 2 * j]
    J = Lw.c_inst * (e0 * e0 + e1 * e1)
    if Lw.n_int > 0:
        D = nw + 1
        m0 = Lw.int0
        acc = xc[m0]
        for j in range(nw):
            fj = 1.0 - s[j]
            if fj != 0.0:
                c = xc[m0 + _tri(np.int64(0), j + 1, D)]  # not a literal 0: one compile of _tri
                for i in range(j):
                    fi = 1.0 - s[i]
                    if fi != 0.0:
                        c += fi * xc[m0 + _tri(i + 1, j + 1, D)]
                # int += f_j (2 c_j + f_j M_jj)
                acc += fj * (2.0 * c + fj * xc[m0 + _tri(j + 1, j + 1, D)])
        J = J + Lw.c_int * acc
    return J


@jit
def switching_costs(Lw, eta, xc):
    """J_(k) (3.46) of every model of the bank, (N,) (``_model_cost`` per pattern)."""
    Nm = Lw.patterns.shape[0]
    J = np.empty(Nm)
    e10 = eta[0] - xc[Lw.hat0]
    e11 = eta[1] - xc[Lw.hat0 + 1]
    for k in range(Nm):
        J[k] = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
    return J


@jit
def switching_costs_rows(Lw, ETA, XC, every):
    """(K, N) costs of every model at K logged states (every = 1), or (K, 2) [J_selected, min_k J_k] (0)."""
    K = XC.shape[0]
    out = np.empty((K, Lw.patterns.shape[0] if every else 2))
    for r in range(K):
        if every:
            out[r] = switching_costs(Lw, ETA[r], XC[r])
        else:
            e10 = ETA[r, 0] - XC[r, Lw.hat0]
            e11 = ETA[r, 1] - XC[r, Lw.hat0 + 1]
            Jc = _model_cost(Lw, XC[r], e10, e11, Lw.patterns[round(XC[r, Lw.sel])])
            out[r, 0] = Jc
            out[r, 1] = _best_cost(Lw, XC[r], e10, e11, Jc)[0]
    return out


@jit
def _walk(Lw, xc, e10, e11, mode, lim):
    r"""Depth-first walk over the 0/1 patterns wheel by wheel: the least J (mode 0, lim = a known cost)
    or the lowest bank index with J <= lim (mode 1).

    Wheel j's branch adds f_j = 1 - sigma_j: etatilde += z_j and int += 2 c_j + M_jj, with
    c_i += M_ji for the wheels i > j still open (the rank-one update of ``_model_cost``'s sums, O(2n)
    per node).  Branches without a bank pattern (``Lw.trie``) are skipped, and so are those whose lower
    bound exceeds lim: every leaf below a node at depth d has, for any unit vector w,
    |etatilde| >= w . etatilde = w . etatilde_node + sum_(i >= d) f_i w . z_i
    >= w . etatilde_node + sum_(i >= d) min(0, w . z_i); with w along etatilde_node (above the last
    three wheels; nearer the leaves the cheaper |etatilde_node| - sum_(i >= d) |z_i|).  For the
    integral, M is positive semidefinite, so v^T M v >= (y^T M v)^2 / (y^T M y) for y = the node's
    (1, f) (Cauchy-Schwarz), and y^T M v >= y^T M y + sum_(i >= d) min(0, (M y)_i).  The bounds are
    lowered by far more than the round-off of the leaf costs (1e-12 relative on etatilde,
    1e-10 D^2 trace(M) on the integral, 1e-9 on the comparison), so no pattern that could be the
    minimum or a tie is skipped.
    The branch that brings etatilde nearer 0 is walked first (a low cost early prunes more; the
    order does not change the result).  In a monotone bank (``trie[0] = 1``: a pattern with one more
    working wheel is in the bank, at a lower index, e.g. every compensable pattern) the branch
    f_d = 1 of a wheel whose filter and integrals are exactly 0 (never driven) is skipped: its costs
    are those of f_d = 0, bit for bit, at higher indices (at t = 0 every model ties).  Returns
    (least J, True if a NaN cost was met) in mode 0, (index, False) in mode 1.
    """
    nw = Lw.patterns.shape[1]
    D = nw + 1
    i0 = Lw.hat0
    use_int = Lw.n_int > 0
    Z = np.empty((nw, 2))  # local copies: the walk reads plain arrays of its own
    for j in range(nw):
        Z[j, 0] = xc[i0 + 2 + 2 * j]
        Z[j, 1] = xc[i0 + 3 + 2 * j]
    M = np.zeros((D, D)) if use_int else np.zeros((1, 1))
    if use_int:
        for a in range(D):
            for b in range(a, D):
                M[a, b] = xc[Lw.int0 + _tri(a, b, D)]
                M[b, a] = M[a, b]
    return _walk_core(
        Lw.codes, Lw.trie, Z, M, use_int, Lw.c_inst, Lw.c_int, e10, e11, mode, lim
    )  # fmt: skip


@jit
def _walk_core(codes, trie, Z, M, use_int, c_inst, c_int, e10, e11, mode, lim):
    """``_walk`` on plain arrays: Z (2n, 2) the wheels' filters, M (2n + 1, 2n + 1) the integrals."""
    nw = Z.shape[0]
    D = nw + 1
    R = np.zeros(nw + 1)  # R[d] = sum_(i >= d) |z_i|
    for j in range(nw - 1, -1, -1):
        R[j] = R[j + 1] + math.sqrt(Z[j, 0] ** 2 + Z[j, 1] ** 2)
    slack = 0.0  # the int part's round-off and M's departure from PSD (far above either)
    if use_int:
        tr = 0.0
        for a in range(D):
            tr += abs(M[a, a])
        slack = c_int * 1e-10 * D * D * tr
    E = np.empty((nw + 1, 2))
    ACC = np.zeros(nw + 1)
    CV = np.zeros((nw + 1, nw)) if use_int else np.zeros((1, 1))
    CODE = np.zeros(nw + 1, dtype=np.int64)
    BR = np.zeros(nw + 1, dtype=np.int64)
    FIRST = np.zeros(nw + 1, dtype=np.int64)  # the f_d walked first at depth d
    SAME = np.zeros(nw, dtype=np.bool_)  # f_d = 1 gives f_d = 0's costs at a higher index: skipped
    if trie[0] == 1:
        for j in range(nw):
            zero = Z[j, 0] == 0.0 and Z[j, 1] == 0.0
            if use_int:
                for a in range(D):
                    zero = zero and M[a, j + 1] == 0.0
            SAME[j] = zero
    E[0, 0] = e10
    E[0, 1] = e11
    if use_int:
        ACC[0] = M[0, 0]
        for j in range(nw):
            CV[0, j] = M[0, j + 1]
    best = lim
    nan = False
    found = -1
    d = 0
    while d >= 0:
        if d == nw:
            k = codes[CODE[d]]
            if k >= 0:
                cost = c_inst * (E[d, 0] * E[d, 0] + E[d, 1] * E[d, 1])
                if use_int:
                    cost = cost + c_int * ACC[d]
                if mode == 0:
                    if cost < best:
                        best = cost
                    elif math.isnan(cost):
                        nan = True
                elif cost <= lim and (found < 0 or k < found):
                    found = k
            d -= 1
            continue
        if BR[d] == 0:
            a0 = E[d, 0] + Z[d, 0]
            a1 = E[d, 1] + Z[d, 1]
            FIRST[d] = 1 if a0 * a0 + a1 * a1 < E[d, 0] * E[d, 0] + E[d, 1] * E[d, 1] else 0
        elif BR[d] == 2:
            d -= 1
            continue
        b = FIRST[d] if BR[d] == 0 else 1 - FIRST[d]  # f_d of this branch
        BR[d] += 1
        if b == 1 and SAME[d]:
            continue
        code = CODE[d] | ((1 - b) << d)  # bit d = sigma_d
        if trie[(1 << (d + 1)) + code] == 0:
            continue
        c = d + 1
        if b == 0:  # wheel d works: f_d = 0
            E[c, 0] = E[d, 0]
            E[c, 1] = E[d, 1]
            if use_int:
                ACC[c] = ACC[d]
                for i in range(c, nw):
                    CV[c, i] = CV[d, i]
        else:  # wheel d failed: f_d = 1
            E[c, 0] = E[d, 0] + Z[d, 0]
            E[c, 1] = E[d, 1] + Z[d, 1]
            if use_int:
                ACC[c] = ACC[d] + (2.0 * CV[d, d] + M[d + 1, d + 1])
                for i in range(c, nw):
                    CV[c, i] = CV[d, i] + M[d + 1, i + 1]
        # lower bound of J below this node: c_inst (inst. bound) + c_int (integral bound) - slack
        ib = 0.0
        if use_int and ACC[c] > 0.0:
            # int = v^T M v >= (y^T M v)^2 / (y^T M y) with y = this node's (1, f) (Cauchy-Schwarz),
            # y^T M v >= int_node + sum_(i >= c) min(0, c_i) = L
            L = ACC[c]
            for i in range(c, nw):
                if CV[c, i] < 0.0:
                    L += CV[c, i]
            if L > 0.0:
                ib = c_int * (L * L / ACC[c])
        r = math.sqrt(E[c, 0] * E[c, 0] + E[c, 1] * E[c, 1])
        gap = r - R[c] - 1e-12 * (r + R[c])
        bound = c_inst * gap * gap if gap > 0.0 else 0.0
        if (bound + ib - slack) * (1.0 - 1e-9) > best:
            continue
        if nw - c >= 3 and r > 0.0:
            # w = etatilde_node / |etatilde_node|: |etatilde| >= r + sum_(i >= c) min(0, w . z_i)
            w0 = E[c, 0] / r
            w1 = E[c, 1] / r
            acc = r
            for i in range(c, nw):
                p = w0 * Z[i, 0] + w1 * Z[i, 1]
                if p < 0.0:
                    acc += p
            gap = acc - 1e-12 * (r + R[c])
            bound = c_inst * gap * gap if gap > 0.0 else 0.0
            if (bound + ib - slack) * (1.0 - 1e-9) > best:
                continue
        CODE[c] = code
        BR[c] = 0
        d = c
    if mode == 0:
        return best, nan
    return float(found), False


@jit
def _good_cost(Lw, xc, e10, e11):
    """The cost of a good bank pattern, the walk's first upper bound: wheel by wheel the branch of lower
    partial cost (the wheels after it assumed working), then single-wheel changes while one lowers J.

    A cost of a pattern of the bank, computed by ``_model_cost`` (the walk's bits): only a bound, the
    walk still finds the least cost.  Without it a poor applied model (during the dwell time or
    behind the hysteresis) leaves the walk a poor bound and many more nodes to visit.
    """
    nw = Lw.patterns.shape[1]
    i0 = Lw.hat0
    s = np.ones(nw)
    code = 0
    e0 = e10
    e1 = e11
    for d in range(nw):
        a0 = e0 + xc[i0 + 2 + 2 * d]
        a1 = e1 + xc[i0 + 3 + 2 * d]
        keep = Lw.trie[(1 << (d + 1)) + (code | (1 << d))] == 1  # wheel d working is in the bank
        fail = Lw.trie[(1 << (d + 1)) + code] == 1
        if fail and (not keep or a0 * a0 + a1 * a1 < e0 * e0 + e1 * e1):
            s[d] = 0.0
            e0 = a0
            e1 = a1
        else:
            code |= 1 << d
    best = _model_cost(Lw, xc, e10, e11, s)
    for _ in range(nw):
        moved = False
        for j in range(nw):
            c2 = code ^ (1 << j)
            k = Lw.codes[c2]
            if k >= 0:
                Jn = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
                if Jn < best:
                    best = Jn
                    code = c2
                    moved = True
        if not moved:
            break
    return best


@jit
def _best_cost(Lw, xc, e10, e11, Jc):
    """min_k J_(k) over the bank (``_walk`` for a 0/1 bank with its table, else every pattern), and NaN seen."""
    if Lw.codes.shape[0] > 0:
        Jg = _good_cost(Lw, xc, e10, e11)
        lim = Jc if not math.isnan(Jc) else np.inf
        # np.int64: a literal mode would compile _walk and _walk_core once per mode (issue 20 item 1)
        return _walk(Lw, xc, e10, e11, np.int64(0), Jg if Jg < lim else lim)
    best = np.inf
    nan = False
    for k in range(Lw.patterns.shape[0]):
        cost = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
        if cost < best:
            best = cost
        elif math.isnan(cost):
            nan = True
    return best, nan


@jit
def switching_select(Lw, t, eta, xc):
    r"""The switching rule (3.47)-(3.48): the model of least cost J_k (3.46), with dwell time and hysteresis.

    J_k = c_inst |eta - etahat_k|^2 + c_int int_k (``_model_cost``); ties within TIE_RTOL of the least
    cost go to the lowest index.  The selection changes only after T_min since the last switch and
    when it lowers J by the hysteresis.  The least cost and the tied candidates are found by
    ``_walk`` for a 0/1 bank (no per-model work: it skips the subtrees that cannot win), by
    evaluating every pattern otherwise; the same bits either way.  A NaN cost anywhere keeps the
    applied model (as argmin + the comparisons of the exhaustive rule do).
    """
    if t - xc[Lw.tsw] < Lw.T_min - 1e-12:
        return
    cur = round(xc[Lw.sel])
    e10 = eta[0] - xc[Lw.hat0]
    e11 = eta[1] - xc[Lw.hat0 + 1]
    Jc = _model_cost(Lw, xc, e10, e11, Lw.patterns[cur])
    m, nan = _best_cost(Lw, xc, e10, e11, Jc)
    if nan or math.isnan(Jc):
        return
    lim = m * (1.0 + TIE_RTOL)  # ties (round-off) -> lowest index
    if lim < m:
        lim = m  # a negative least cost (round-off of the integral): exact ties only, as argmin
    if Lw.codes.shape[0] > 0:
        cand = round(_walk(Lw, xc, e10, e11, np.int64(1), lim)[0])
        Jn = _model_cost(Lw, xc, e10, e11, Lw.patterns[cand])
    else:
        cand = -1
        Jn = np.inf
        for k in range(Lw.patterns.shape[0]):
            cost = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
            if cost <= lim:
                cand = k
                Jn = cost
                break
    if cand >= 0 and cand != cur and Jn < Jc - Lw.hysteresis:
        xc[Lw.sel] = cand
        xc[Lw.tsw] = t


@jit
def rotor_filter_terms(pc, q, eta, Jw):
    r"""(MB, g) of the bank's filters (3.42) for a chain whose wheels carry rotors of inertia Jw (issue 36 item 3).

    With a DC motor on each wheel the rotor's inertia eta_g N^2 J_m turns with the wheel (ERRATA E19,
    model.motor_compiled.motor_plant_rhs): (Mbar1 + Bbar Jw Bbar^T) etadot = Bbar (tau - Jw Bbardot^T eta) -
    Mbar2 eta - Cbar, so etadot = g + MB tau with MB = A^-1 Bbar, g = -A^-1 (Mbar2 eta + Cbar +
    Bbar Jw Bbardot^T eta), A = Mbar1 + Bbar Jw Bbar^T.  The law's own (3.37) keeps the chain's model.
    """
    Mbar1, Mbar2, Cbar, Bbar, S, Sd = reduced(pc, q, eta)
    Bbd = bbar_rate(pc, q, eta, S, Sd)
    A = rotor_mass(Mbar1, Bbar, Jw)
    nw = Bbar.shape[1]
    r = _mv(Mbar2, eta) + Cbar
    for j in range(nw):
        # + Bbar_j Jw_j (Bbardot^T eta)_j
        wd = Jw[j] * (Bbd[0, j] * eta[0] + Bbd[1, j] * eta[1])
        r[0] += Bbar[0, j] * wd
        r[1] += Bbar[1, j] * wd
    g = -_solve2(A, r)
    MB = np.empty((2, nw))
    col = np.empty(2)
    for j in range(nw):
        col[0] = Bbar[0, j]
        col[1] = Bbar[1, j]
        MB[:, j] = _solve2(A, col)
    return MB, g
