"""The chained form derived with sympy: the independent check of the compiled map (fast.kernels.xi_T).

Theorem 2.1 / Appendix E (Sordalen), thesis numbering (2.75): xi_1 = x, xi_m = y,
xi_(m-1) = tan(theta_n), xi_(k-1) = (L_g1 xi_k) / cos(theta_n), g1 the first column of S(q)
(2.64); T_alpha = [[cos theta_n, 0], [L_g1 xi_2, d xi_2 / d theta_1]].  It was
``ftcreport.model.chained.symbolic_chained_form``; nothing in the package runs it.
"""

from __future__ import annotations

from functools import lru_cache


@lru_cache(maxsize=16)
def symbolic_chained_form(n: int):
    """Symbolic derivation for n robots, lambdified: ``(f_xi(th, d), f_T(th, d))`` (tests only).

    ``f_xi`` gives xi_2..xi_(m-1) and ``f_T`` gives (T21, T22) at headings ``th`` in robot
    order; the independent check of the numeric map (Theorem 2.1, Appendix E).
    """
    import sympy as sp

    th = sp.symbols(f"th1:{n + 1}", real=True)  # robot order theta_1..theta_n
    d = sp.symbols(f"d1:{n}", positive=True)
    x, y = sp.symbols("x y", real=True)
    # first column of S, thetadot_k / v_n (robot order), from (2.64)
    g1 = [sp.Integer(0)] * n
    for i in range(n - 1):  # theta_(i+2) driven by phi_(i+1) = theta_(i+1) - theta_(i+2)
        w = sp.Integer(1)
        for j in range(i + 1, n - 1):
            w = w / sp.cos(th[j] - th[j + 1])
        g1[i + 1] = sp.tan(th[i] - th[i + 1]) / d[i] * w
    m = n + 2
    xi = [None] * (m + 1)  # 1-based
    xi[1] = x
    xi[m] = y
    xi[m - 1] = sp.tan(th[n - 1])
    cn = sp.cos(th[n - 1])

    def lie(expr):
        return sum(sp.diff(expr, th[k]) * g1[k] for k in range(n))

    for k in range(m - 1, 2, -1):
        xi[k - 1] = lie(xi[k]) / cn
    T21 = lie(xi[2])
    T22 = sp.diff(xi[2], th[0])
    ang = [xi[k] for k in range(2, m)]  # xi_2..xi_(m-1): functions of the angles only
    f_xi = sp.lambdify([th, d], ang, modules="numpy", cse=True)
    f_T = sp.lambdify([th, d], [T21, T22], modules="numpy", cse=True)
    return f_xi, f_T
