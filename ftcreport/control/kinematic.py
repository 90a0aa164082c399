r"""Kinematic controllers: eta_c, T_alpha and f_eta for the dynamic layer.

Both laws exist once, in the compiled kernels (``control.kinematic_compiled._two_link_law`` and
``_chained_law``, with their equations and errata); the classes here hold and
check the gains, pack them (``packed(h)``, the kernels' ``Kin`` tuple) and call
the kernels.  Two designs, both returning a :class:`KinematicOutput` from ``law(t, q, xc)``
with ``alpha = T_alpha eta + f_alpha`` and the Lyapunov cross term ``f_eta`` that
the dynamic law cancels with ``-T_alpha^T f_eta`` (ERRATA E8):

* :class:`TwoLinkKinematic` -- the two-link diffeomorphism controller of thesis
  section 3.2.2.1 (3.8-3.29, Appendices F, G) with ERRATA E6, E7, E9, E11a.
* :class:`ChainedBackstepping` -- recursive backstepping on the chained form
  for any n (thesis 3.67-3.106 for n = 3, Jiang & Nijmeijer 1999), with explicit
  gains on every virtual control (ERRATA E12d) and the corrections E12a-E12c,
  in a frame re-anchored to the reference heading (beyond the thesis).

Backstepping for any n (derivation used here)
----------------------------------------------
With m = n + 2 chained states, errors xi_e = xi - xi_d and p = m - 1, set
``Z_j = xi_e,(m+1-j) - xi_(m-j) xi_e,1`` (j = 1..m-2), ``Z_(m-1) = xi_e,2``,
``z = Z_m = xi_e,1`` (3.71 generalized).  Then (3.73 generalized)::

    Z_j'     = alpha_1d Z_(j+1) - xi_(m-1-j) (alpha_1 - alpha_1d) z,   j = 1..m-3
    Z_(m-2)' = alpha_1d Z_(m-1) - alpha_2 z
    Z_(m-1)' = alpha_2 - alpha_2d,      z' = alpha_1 - alpha_1d

Backstepping on the chain Z_1..Z_p with linear virtual controls gives
``Zbar = L Z`` with L unit lower triangular, built row by row::

    row_1 = e_1,   row_(j+1) = row_j N + row_(j-1) + c_j row_j      (N: shift, row_0 = 0)

so that, with z = 0, ``Zbar_j' = alpha_1d (-Zbar_(j-1) - c_j Zbar_j + Zbar_(j+1))``
(c_j = 0 gives the thesis's gain-free beta functions 3.77-3.87).  Then, with
``V = |Zbar|^2 / 2 + kappa z^2 / 2``::

    alpha_2c = alpha_2d - c_a2 Zbar_p - alpha_1d Zbar_(p-1) - alpha_1d row_p N Z        (3.102)
    Delta_1  = sum_(j<=p-2) (L^T Zbar)_j xi_(m-1-j),   Gamma = (L^T Zbar)_(p-1)          (3.93)
    alpha_1c = alpha_1d + (kappa - Delta_1)^-1 (-c_z z + Gamma alpha_2c)                  (3.103)
    f_eta    = [z (kappa - Delta_1), Zbar_p - z Gamma]                                    (3.105, E12c)

and ``V' = -alpha_1d sum_(j<p) c_j Zbar_j^2 - c_a2 Zbar_p^2 - c_z z^2 + f_eta^T alpha_e``.

Length scale (beyond the thesis).  The couplings of the chain above all have
unit coefficient per metre travelled, so for n >= 4 the n + 1 chain modes ask
for lateral corrections within about a metre of travel: from a 0.5 m, 30 deg
offset the leader then folds the chain into a singular configuration.  With
``mu`` [1/m] the design runs on ``Zhat_j = mu^-(j-1) Z_j``, whose chain is
``Zhat_j' = mu alpha_1d Zhat_(j+1)``: every formula above holds with
alpha_1d -> mu alpha_1d, ``Zbar = L Zhat``, the alpha_2 input scaled by
``mu^-(p-1)``::

    alpha_2c = alpha_2d + mu^(p-1) [-c_a2 Zbar_p - mu alpha_1d (Zbar_(p-1) + row_p N Zhat)]
    Delta_1  = rho sum_(j<=p-2) (L^T Zbar)_j mu^-(j-1) xi_(m-1-j),   Gamma = rho (L^T Zbar)_(p-1) mu^-(p-2)
    f_eta    = [z (kappa - Delta_1), rho mu^-(p-1) Zbar_p - z Gamma]

with ``V = rho |Zbar|^2 / 2 + kappa z^2 / 2`` and ``rho = mu^(2(p-1))`` (any rho > 0 is a
valid Lyapunov weight; this one keeps Delta_1, hence kappa - Delta_1, and f_eta at
the magnitudes of the unscaled design).  Every chain eigenvalue (per metre)
scales with mu; mu = 1 (rho = 1) is the design above.
The chain gains need alpha_1d = v_nd cos(theta_nd) > 0: the reference moves
forward and, thanks to re-anchoring, |theta_nd| stays below the band in the frame.

Re-anchoring (paths that turn)
------------------------------
The chained form holds only while |theta_n| < 90 deg in its frame.  The
controller keeps a frame angle psi as discrete state and expresses q and q_d
in the frame rotated by psi.  After every step, if the reference heading
theta_nd leaves psi +/- band (45 deg by default), psi jumps to theta_nd.  v_n and
omega_1 are frame independent, so eta_c stays meaningful; the Lyapunov
function jumps at re-anchoring, by an amount that vanishes with the tracking
error.  Boundedness through re-anchoring is shown by the closed-loop tests on
the circle and the eight.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ModelError, SingularityError, chained_reason, kappa_reason, two_link_reason
from ..model.kernels import wrap  # re-exported: the angle wrap the kinematic laws and the metrics share
from ..references import FlatReference, RefPoint

__all__ = ["ChainedBackstepping", "KinematicOutput", "TwoLinkKinematic", "to_frame", "wrap"]


def _F():
    """The compiled twin of this module (numba is loaded on first use, not with the package)."""
    from . import kinematic_compiled as compiled

    return compiled


def to_frame(q: np.ndarray, psi: float) -> np.ndarray:
    """q expressed in the frame rotated by psi, headings continuous along the chain: the compiled ``to_frame``.

    theta_n is wrapped to [-pi, pi) in the new frame; every other heading keeps its
    (wrapped) articulation angle to its follower.
    """
    q = np.ascontiguousarray(q, dtype=float)
    return _F().to_frame(q, float(psi), np.empty_like(q))


@dataclass(frozen=True)
class KinematicOutput:
    """What the dynamic layer needs from a kinematic controller at one instant.

    Attributes
    ----------
    eta_c : (2,) ndarray
        Kinematic velocity command [v_nc, omega_1c].
    T_alpha : (2, 2) ndarray
        alpha = T_alpha eta + f_alpha.
    f_eta : (2,) ndarray
        Lyapunov cross term: V_kin' = ... + f_eta^T T_alpha (eta - eta_c).
    z : (k,) ndarray
        The controller's error coordinates (logged).
    """

    eta_c: np.ndarray
    T_alpha: np.ndarray
    f_eta: np.ndarray
    z: np.ndarray


class _Face:
    """What both laws share: the kernels' tuples, a work cache, and the call of ``kin_law``."""

    reference: FlatReference
    n: int
    _kin: object = None
    _cache: object = None

    def packed(self, h: float = 1e-5):
        """The law as the compiled kernels take it (``jit.packed.Kin``); h: step of the etadot_c difference."""
        if self._kin is None or self._kin.h != float(h):
            self._kin = self._pack(float(h))
        return self._kin

    def _packed_any(self):
        """The packed law whatever its h (h only sets the kernels' etadot_c difference, unused by a single law)."""
        return self._kin if self._kin is not None else self.packed()

    def _pack(self, h: float):
        raise NotImplementedError

    def _raise(self, info: np.ndarray) -> None:
        F = _F()
        code, a, b = int(info[0]), float(info[1]), float(info[2])
        if code in (F.E_REF_SPEED, F.E_REF_ART):
            self.reference._raise(info)
        if code == F.E_TWO_LINK_ETH:
            raise SingularityError(two_link_reason("heading error e_theta of robot 2", a))
        if code == F.E_TWO_LINK_PHI:
            raise SingularityError(two_link_reason("articulation angle theta_1 - theta_2", a))
        if code == F.E_CHAINED_THN:
            raise SingularityError(chained_reason(f"theta_{self.n}", a, " in its frame"))
        if code == F.E_CHAINED_ART:
            raise SingularityError(chained_reason(f"theta_{int(a) + 1} - theta_{int(a) + 2}", b))
        raise SingularityError(kappa_reason(a))

    def _at(self, r: RefPoint, q: np.ndarray, psi: float) -> KinematicOutput:
        """The law at state q against reference point r (row 0 of the kernels' cache), frame psi."""
        F = _F()
        if self._cache is None:
            self._cache = F.new_cache(self.n)
        C, Kp, R = self._cache, self._packed_any(), self.reference.packed()
        C.f[2] = 0.0  # row 0 is filled here, not by ref_side: the kernels' memo is not valid
        C.QD[0], C.ED[0], C.EDD[0] = r.q_d, r.eta_d, r.eta_d_dot
        C.SC[0] = (r.v_d, r.omega_d, r.v_d_dot, r.omega_d_dot)
        if Kp.kind == F.KIN_CHAINED:
            F.xi_T(F.to_frame(C.QD[0], psi, C.WQ), R.d, C.WJ, C.XID[0], C.TD[0])
        info = np.zeros(4)
        F.kin_law(Kp, R, C, 0, np.ascontiguousarray(q, dtype=float), np.array([psi]), info)
        if info[0] != 0:
            self._raise(info)
        return KinematicOutput(C.KEC[0].copy(), C.KT[0].copy(), C.KF[0].copy(), C.KZ[0].copy())

    def law_and_rate(
        self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray, S: np.ndarray, h: float = 1e-5
    ) -> tuple[KinematicOutput, np.ndarray]:
        """The law at t and etadot_c, its derivative along (qdot = S eta, 1) (ERRATA P5): the compiled
        ``eta_c_and_dot``, a central difference of step h on the law (the reference from its jets at t)."""
        F = _F()
        if self._cache is None:
            self._cache = F.new_cache(self.n)
        info = np.zeros(4)
        xk = np.array([float(xc[0])]) if self.n_states else np.zeros(1)
        v = (np.ascontiguousarray(x, dtype=float) for x in (S, q, eta))
        S, q, eta = v
        kin, ecd = F.eta_c_and_dot(self.packed(h), self.reference.packed(), self._cache, S, float(t), q, eta, xk, info)
        if info[0] != 0:
            self._raise(info)
        return KinematicOutput(*(a.copy() for a in kin)), ecd


class TwoLinkKinematic(_Face):
    r"""Two-link diffeomorphism controller, thesis (3.8)-(3.29), ERRATA E6-E11a.

    Errors (3.8)-(3.10) ``e = T_e (q - q_d)`` of robot 2 against the unicycle
    reference, ``phi = theta_1 - theta_2``, then (3.14)-(3.17) with E6::

        z1 = e_x, z2 = e_y, z3 = tan e_theta,
        z4 = tan(phi) / (d cos^3 e_theta) - omega_d / (v_d cos^2 e_theta) + e_y

    ``alpha_1 = v_2 cos e_theta - v_d`` (E11a), ``alpha_2 = z4'``, so that
    ``z1' = omega_d z2 + alpha_1``, ``z2' = -omega_d z1 + (v_d + alpha_1) z3``,
    ``z3' = v_d (z4 - z2) + alpha_1 (z4 - z2 + (omega_d/v_d)(1 + z3^2))`` (E7),
    ``z4' = alpha_2``.  T_alpha and f_alpha (in the kernel ``_two_link_law``) are
    derived by differentiating z4 (Appendix G with E6) and tested against finite
    differences.

    Parameters
    ----------
    d : float
        Link length |P_1 P_2| [m].
    reference : FlatReference
        Supplies x_d, y_d, theta_d, v_d, omega_d and their derivatives (robot 2).
    k1, k2, k3 : float
        Gains of (3.27)-(3.28), k1, k2, k3 > 0.
    """

    n_states = 0
    n = 2
    z_names = ("z1", "z2", "z3", "z4")

    def __init__(self, d: float, reference: FlatReference, k1: float, k2: float, k3: float) -> None:
        if reference.n != 2:
            raise ModelError(f"reference: the two-link controller needs a 2-robot reference, got n = {reference.n}")
        for name, val in (("k1", k1), ("k2", k2), ("k3", k3)):
            if not val > 0:
                raise ModelError(f"{name}: must be > 0, got {val}")
        self.d = float(d)
        self.reference = reference
        self.k1, self.k2, self.k3 = float(k1), float(k2), float(k3)

    def _pack(self, h: float):
        F = _F()
        e1 = np.zeros(1)
        return F.Kin(
            F.KIN_TWO_LINK, 2, self.d, self.k1, self.k2, self.k3, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            np.zeros((1, 1)), e1, e1, 1.0, h, 0,
        )  # fmt: skip

    def initial_state(self, t: float, q: np.ndarray) -> np.ndarray:
        return np.zeros(0)

    def discrete(self, t: float, q: np.ndarray, xc: np.ndarray) -> np.ndarray:
        return xc

    def zcoords(self, q: np.ndarray, r: RefPoint) -> np.ndarray:
        """(z1..z4) (3.14)-(3.17) with E6 at state q and reference point r."""
        return self._at(r, q, 0.0).z

    def law(self, t: float, q: np.ndarray, xc: np.ndarray) -> KinematicOutput:
        """eta_c (3.29), T_alpha, f_eta at time t and state q."""
        return self._at(self.reference.at(t), q, 0.0)

    def f_alpha(self, t: float, q: np.ndarray) -> np.ndarray:
        """f_alpha of alpha = T_alpha eta + f_alpha (3.29, Appendix G with E10): the compiled law's own.

        Exposed for tests and the linearized analysis.
        """
        self._at(self.reference.at(t), q, 0.0)
        return self._cache.KA[0].copy()


class ChainedBackstepping(_Face):
    r"""Recursive backstepping on the chained form for any n, with re-anchoring (kernel ``_chained_law``).

    Parameters
    ----------
    d : sequence of float
        Link lengths d_1..d_(n-1) [m].
    reference : FlatReference
        Reference of the whole chain.
    c_chain : sequence of float
        Gains c_1..c_n of the n virtual controls (>= 0; the thesis uses none,
        ERRATA E12d recommends 0.2-0.5).
    c_alpha2 : float
        Gain of Zbar_p in alpha_2c (the thesis's c4), > 0.
    c_xi1 : float
        Gain of z = xi_e,1 in alpha_1c (the thesis's c5), > 0.
    kappa : float
        Weight of z in the Lyapunov function, > 0; kappa - Delta_1 must stay away from 0.
    band : float
        Re-anchor the frame when |theta_nd - psi| exceeds this [rad] (< 90 deg).
    mu : float
        Length scale of the chain dynamics [1/m], > 0 (1 = the thesis design).
    """

    n_states = 1  # the frame angle psi

    def __init__(
        self,
        d: Sequence[float],
        reference: FlatReference,
        c_chain: Sequence[float],
        c_alpha2: float,
        c_xi1: float,
        kappa: float,
        band: float = math.radians(45.0),
        mu: float = 1.0,
        singular_tol: float = 1e-2,
    ) -> None:
        self.d = tuple(float(v) for v in d)
        self.n = len(self.d) + 1
        if self.n < 2:
            raise ModelError("d: the chained form needs at least 2 robots")
        self.m = self.n + 2
        if reference.n != self.n:
            raise ModelError(f"reference: built for {reference.n} robots, controller for {self.n}")
        p = self.m - 1
        c = np.asarray(c_chain, dtype=float)
        if c.shape != (p - 1,):
            raise ModelError(f"c_chain: expected {p - 1} gains for {self.n} robots, got {c.shape[0]}")
        if np.any(c < 0):
            raise ModelError(f"c_chain: gains must be >= 0, got {c.tolist()}")
        for name, val in (("c_alpha2", c_alpha2), ("c_xi1", c_xi1), ("kappa", kappa)):
            if not val > 0:
                raise ModelError(f"{name}: must be > 0, got {val}")
        if not mu > 0:
            raise ModelError(f"mu: length scale must be > 0 1/m, got {mu}")
        if not 0 < band < math.pi / 2:
            raise ModelError(f"band: must be in (0, 90) deg, got {math.degrees(band):.1f} deg")
        self.reference = reference
        self.c_chain = c
        self.c_alpha2, self.c_xi1, self.kappa = float(c_alpha2), float(c_xi1), float(kappa)
        self.band = float(band)
        self.mu = float(mu)
        self.Dscale = float(mu) ** -np.arange(p)  # Zhat_j = mu^-(j-1) Z_j
        self.rho = float(mu) ** (2 * (p - 1))  # Lyapunov weight of the chain part
        self.singular_tol = float(singular_tol)
        self.p = p
        # shift N: (N Z)_j = Z_(j+1) for j < p
        N = np.zeros((p, p))
        N[np.arange(p - 1), np.arange(1, p)] = 1.0
        L = np.zeros((p, p))
        L[0, 0] = 1.0
        prev = np.zeros(p)
        for j in range(p - 1):
            # row_(j+1) = row_j N + row_(j-1) + c_j row_j
            L[j + 1] = L[j] @ N + prev + c[j] * L[j]
            prev = L[j]
        self.N = N
        self.L = L
        self.LN_last = L[p - 1] @ N
        self.z_names = tuple(f"Z{j + 1}" for j in range(self.m))

    def _pack(self, h: float):
        F = _F()
        return F.Kin(
            F.KIN_CHAINED, self.n, 0.0, 0.0, 0.0, 0.0, self.c_alpha2, self.c_xi1, self.kappa, self.band, self.mu,
            self.singular_tol, np.ascontiguousarray(self.L), np.ascontiguousarray(self.LN_last, dtype=float),
            np.ascontiguousarray(self.Dscale, dtype=float), float(self.rho), h, 1,
        )  # fmt: skip

    # ------------------------------------------------------------ discrete state
    def initial_state(self, t: float, q: np.ndarray) -> np.ndarray:
        return np.array([self.reference.at(t).theta_d])

    def discrete(self, t: float, q: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """Re-anchor the frame when the reference heading leaves psi +/- band: the compiled ``kin_discrete``."""
        F = _F()
        if self._cache is None:
            self._cache = F.new_cache(self.n)
        out = np.array(xc, dtype=float)
        info = np.zeros(4)
        F.kin_discrete(self._packed_any(), self.reference.packed(), self._cache, float(t), out, info)
        if info[0] != 0:
            self._raise(info)
        return out if out[0] != xc[0] else xc

    def discrete_along(self, times: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """psi after :meth:`discrete` at each of ``times`` in turn from ``xc``, in one compiled walk (the same
        numbers: ``kin_discrete`` at each time): the compiled ``kin_discrete_along``."""
        F = _F()
        if self._cache is None:
            self._cache = F.new_cache(self.n)
        info = np.zeros(4)
        ts, x = np.ascontiguousarray(times, dtype=float), np.array(xc, dtype=float)
        out = F.kin_discrete_along(self._packed_any(), self.reference.packed(), self._cache, ts, x, info)
        if info[0] != 0:
            self._raise(info)
        return out

    # ------------------------------------------------------------ the law
    def law(self, t: float, q: np.ndarray, xc: np.ndarray) -> KinematicOutput:
        """eta_c (3.98)-(3.106) generalized, T_alpha, f_eta (3.105, E12c) and Z at time t, state q, frame xc[0]."""
        return self._at(self.reference.at(t), q, float(xc[0]))
