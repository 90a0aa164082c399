r"""Chained form of the n-link kinematics, Theorem 2.1 / Appendix E (Sordalen).

With ``m = n + 2`` chained coordinates (thesis numbering, 2.75)::

    xi_1 = x,   xi_m = y,   xi_(m-1) = tan(theta_n),
    xi_(k-1) = (L_g1 xi_k) / cos(theta_n),  k = m-1, ..., 3

where ``g1`` is the first column of S(q) (the v_n direction), so ``xi_(k-1)`` is
the derivative of ``xi_k`` with respect to x along the motion.  Then::

    xi_1' = alpha_1,  xi_2' = alpha_2,  xi_k' = xi_(k-1) alpha_1  (k >= 3)
    alpha = T_alpha(q) eta,   T_alpha = [[cos theta_n, 0], [L_g1 xi_2, d xi_2 / d theta_1]]

The map is computed numerically, for any n, by Taylor-mode differentiation
along the flow of g1 (``model.chained_compiled.chained_xi_T``, compiled; its
docstring and the kernels' module docstring give the recursion): one
implementation, used by the compiled engine and by this class alike.
The same map derived with sympy (in the link lengths as symbols,
tests/chained_reference.py) is the independent check the tests compare against
(tests/test_fast.py, to 1e-12 for n = 2..5).  Both
replace the thesis's hand-printed three-link formulas, which ERRATA E5e-E5g
list as wrong.  Valid while |theta_n| < 90 deg and every articulation
angle |theta_i - theta_(i+1)| < 90 deg (the backstepping kernel refuses
states outside, ``control.kinematic_compiled._chained_law``).

The inverse map uses that ``xi_(m-1-j)`` is the first coordinate to depend on
theta_(n-j) and is affine in ``tan(theta_(n-j) - theta_(n-j+1))``: the angles are
recovered one by one in closed form.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ModelError, SingularityError

__all__ = ["ChainedForm"]


class ChainedForm:
    """Chained-form map of an n-robot chain with link lengths d (leader first).

    Parameters
    ----------
    d : (n - 1,) sequence of float
        Link lengths d_1..d_(n-1) [m].
    """

    def __init__(self, d) -> None:
        self.d = tuple(float(v) for v in d)
        self.n = len(self.d) + 1
        if self.n < 2:
            raise ModelError("d: the chained form needs at least 2 robots")
        self.m = self.n + 2
        self._d = np.asarray(self.d, dtype=float).reshape(-1)

    def _ang(self, th: np.ndarray) -> tuple[np.ndarray, float, float]:
        """xi_2..xi_(m-1) and (T21, T22) at headings th (robot order): the compiled kernel."""
        from .chained_compiled import chained_xi_T

        ang = np.empty(self.n)
        work = np.zeros((9 * self.n, self.n + 2))
        T21, T22 = chained_xi_T(np.ascontiguousarray(th, dtype=float), self._d, work, ang)
        return ang, float(T21), float(T22)

    def xi(self, q: np.ndarray) -> np.ndarray:
        r"""Chained coordinates xi = phi(q), (n + 2,), thesis numbering xi_1..xi_m."""
        return self.xi_and_T(q)[0]

    def T_alpha(self, q: np.ndarray) -> np.ndarray:
        """Input map alpha = T_alpha(q) eta, (2, 2)."""
        return self.xi_and_T(q)[1]

    def xi_and_T(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(xi(q), T_alpha(q))`` in one call: the compiled ``xi_T``."""
        from .chained_compiled import xi_T

        xi, T = np.empty(self.m), np.empty((2, 2))
        xi_T(np.ascontiguousarray(q, dtype=float), self._d, np.zeros((9 * self.n, self.n + 2)), xi, T)
        return xi, T

    def inverse(self, xi: np.ndarray) -> np.ndarray:
        """q = phi^-1(xi) on the domain |theta_n|, |articulations| < 90 deg."""
        xi = np.asarray(xi, dtype=float)
        if xi.shape != (self.m,):
            raise ModelError(f"xi: expected {self.m} values, got shape {xi.shape}")
        n, m = self.n, self.m
        th = np.zeros(n)  # robot order
        th[n - 1] = math.atan(xi[m - 2])  # xi_(m-1) = tan(theta_n), 0-based index m-2
        for j in range(1, n):
            i = n - 1 - j  # 0-based robot index of the new angle theta_(n-j)
            k = m - 1 - j  # thesis index of the coordinate that first depends on it
            th[i] = th[i + 1]
            a0 = self._ang(th)[0][k - 2]
            th[i] = th[i + 1] + math.pi / 4
            a1 = self._ang(th)[0][k - 2] - a0  # coefficient of tan(phi)
            if a1 == 0:
                raise SingularityError("chained form inverse: degenerate coefficient")
            th[i] = th[i + 1] + math.atan((xi[k - 1] - a0) / a1)
        return np.concatenate(([xi[0], xi[m - 1]], th[::-1]))
