r"""Linearized analyses with python-control (pure: no I/O).

Two-link closed loop at zero error (constant v_d, omega_d)
----------------------------------------------------------
With a constant-velocity unicycle reference, the closed loop of the two-link
kinematic controller (3.27)-(3.29) and a matched dynamic law (3.35) is
autonomous in its error coordinates ``x = [z1, z2, z3, z4, eta_e1, eta_e2]``::

    z' = (3.19)-(3.22) with alpha = alpha_c(z) + T_alpha(z) eta_e       (E7)
    eta_e' = -k_v eta_e - T_alpha(z)^T f_eta(z)                          (matched law)

T_alpha, alpha_c and f_eta are the project's own :class:`TwoLinkKinematic`
(the state q is rebuilt from z, the inverse of 3.14-3.17).  The system is a
``control.nlsys``; ``control.linearize`` gives its Jacobian at 0, checked
against :func:`two_link_error_jacobian` (analytic) in the tests, and its poles
predict the convergence rate (ERRATA P1: the circle gains of 3.3.2.3 give
-1.93, -0.22, -0.025 +/- 0.786j for the kinematic part).

Controllability per failure pattern
-----------------------------------
The velocity loop about the reference motion, closed by the dynamic law's
-k_v eta_e (the Hurwitz part), is ``eta_e' = -k_v eta_e + Mbar1^-1 Bbar sigma v``;
the rank of ctrb(A, B sigma) is 2 exactly for the compensable patterns, and the
smallest eigenvalue of the controllability Gramian (``control.gram``) measures
how close a pattern is to uncompensable.
"""

from __future__ import annotations

import itertools
import math

import control
import numpy as np

from ..control.kinematic import TwoLinkKinematic
from ..errors import FtcError, ModelError
from ..model import kernels as K
from ..model.chain import Chain
from ..model.faults import pattern_is_compensable
from ..references import FlatReference, unicycle

__all__ = [
    "kinematic_error_matrix",
    "pattern_controllability",
    "pole_table",
    "two_link_error_jacobian",
    "two_link_error_system",
]


class _TwoLinkError:
    """Error dynamics of the two-link closed loop built on the project's controller."""

    def __init__(self, d: float, v_d: float, omega_d: float, k1: float, k2: float, k3: float, k_v: float):
        self.d, self.v_d, self.omega_d = float(d), float(v_d), float(omega_d)
        self.k_v = float(k_v)
        self.ref = FlatReference(unicycle(v_d, omega_d), [d])
        self.kin = TwoLinkKinematic(d, self.ref, k1, k2, k3)
        self.r0 = self.ref.at(0.0)

    def q_from_z(self, z: np.ndarray) -> np.ndarray:
        """Inverse of (3.14)-(3.17) at t = 0 (E6)."""
        r = self.r0
        z1, z2, z3, z4 = z
        eth = math.atan(z3)
        c = math.cos(eth)
        # z4 = tan(phi) / (d c^3) - omega_d / (v_d c^2) + e_y
        tphi = self.d * c**3 * (z4 + self.omega_d / (self.v_d * c**2) - z2)
        thd = r.theta_d
        x = r.q_d[0] + math.cos(thd) * z1 - math.sin(thd) * z2
        y = r.q_d[1] + math.sin(thd) * z1 + math.cos(thd) * z2
        th2 = thd + eth
        return np.array([x, y, th2, th2 + math.atan(tphi)])

    def rhs(self, t, x, u, params) -> np.ndarray:
        z, eta_e = x[:4], x[4:]
        q = self.q_from_z(z)
        out = self.kin.law(0.0, q, np.zeros(0))
        # alpha = T_alpha (eta_c + eta_e) + f_alpha = alpha_c + T_alpha eta_e   (3.29)
        a1, a2 = out.T_alpha @ (out.eta_c + eta_e) + self.kin.f_alpha(0.0, q)
        vd, wd = self.v_d, self.omega_d
        z1, z2, z3, z4 = z
        zdot = np.array(
            [
                wd * z2 + a1,  # (3.19)
                -wd * z1 + (vd + a1) * z3,  # (3.20)
                vd * (z4 - z2) + a1 * (z4 - z2 + (wd / vd) * (1.0 + z3**2)),  # (3.21) with E7
                a2,  # (3.22)
            ]
        )
        eta_e_dot = -self.k_v * eta_e - out.T_alpha.T @ out.f_eta
        return np.concatenate((zdot, eta_e_dot))


def two_link_error_system(
    d: float, v_d: float, omega_d: float, k1: float, k2: float, k3: float, k_v: float
) -> control.NonlinearIOSystem:
    """The 6-state closed-loop error dynamics as a python-control nonlinear system."""
    err = _TwoLinkError(d, v_d, omega_d, k1, k2, k3, k_v)
    return control.nlsys(err.rhs, None, states=6, inputs=0, outputs=6, name="two_link_error")


def kinematic_error_matrix(v_d: float, omega_d: float, k1: float, k2: float, k3: float) -> np.ndarray:
    """Analytic Jacobian at z = 0 of (3.19)-(3.22) closed by alpha_c (perfect velocity loop)."""
    r = omega_d / v_d
    return np.array(
        [
            [-k1, omega_d, -k1 * r, 0.0],
            [-omega_d, 0.0, v_d, 0.0],
            [-k1 * r, -v_d, -k1 * r * r, v_d],
            [0.0, 0.0, -k2 * v_d, -k3],
        ]
    )


def two_link_error_jacobian(
    d: float, v_d: float, omega_d: float, k1: float, k2: float, k3: float, k_v: float
) -> np.ndarray:
    """Analytic 6 x 6 Jacobian at zero error of :func:`two_link_error_system`.

    At z = 0: e_theta = 0, tan(phi0) = d omega_d / v_d, T_alpha = [[1, 0], [T21, T22]]
    with T21 = -sec^2(phi0) tan(phi0) / d^2, T22 = sec^2(phi0) / d; f_eta is linear
    to first order: f_eta = [z1 + (omega_d/v_d) z3, z4 / k2].
    """
    r = omega_d / v_d
    tphi = d * r
    sec2 = 1.0 + tphi**2
    T = np.array([[1.0, 0.0], [-sec2 * tphi / d**2, sec2 / d]])
    A = np.zeros((6, 6))
    A[:4, :4] = kinematic_error_matrix(v_d, omega_d, k1, k2, k3)
    # alpha_e = T eta_e enters z1' and z4' directly and z3' through alpha_1 (omega_d/v_d)
    A[0, 4:] = T[0]
    A[2, 4:] = r * T[0]
    A[3, 4:] = T[1]
    Df = np.array([[1.0, 0.0, r, 0.0], [0.0, 0.0, 0.0, 1.0 / k2]])
    A[4:, :4] = -T.T @ Df
    A[4:, 4:] = -k_v * np.eye(2)
    return A


def pole_table(A: np.ndarray) -> list[dict]:
    """Poles with natural frequency, damping and time constant (control.damp)."""
    sys = control.ss(A, np.zeros((A.shape[0], 1)), np.eye(A.shape[0]), 0)
    with np.errstate(invalid="ignore", divide="ignore"):  # a pole at 0 has no damping ratio
        wn, zeta, poles = control.damp(sys, doprint=False)
    out = []
    for p, w, z in sorted(zip(poles, wn, zeta, strict=True), key=lambda e: -e[0].real):
        out.append(
            {
                "re": float(p.real),
                "im": float(p.imag),
                "wn": float(w),
                "damping": float(z) if math.isfinite(z) else None,
                "time_constant": (math.inf if p.real >= 0 else float(-1.0 / p.real)),
            }
        )
    return out


#: chains with at most this many wheels get every 0/1 pattern enumerated (2^8 = 256 for 4 robots);
#: longer ones the patterns with at most MAX_FAILED failed wheels (issue 20 item 6)
FULL_ENUMERATION_WHEELS = 8
MAX_FAILED = 2


def fault_patterns(n_wheels: int, max_failed: int | None = None) -> list[tuple[int, ...]]:
    """0/1 patterns (1 = the wheel works), healthy first, then by number of failed wheels.

    Every pattern (2^(2n)) when ``max_failed`` is None, else those with at most
    ``max_failed`` failed wheels: 1 + 2n + C(2n, 2) for two (301 for 12 robots, against 2^24).
    """
    k_max = n_wheels if max_failed is None else min(max_failed, n_wheels)
    out = []
    for k in range(k_max + 1):
        for failed in itertools.combinations(range(n_wheels), k):
            pat = [1] * n_wheels
            for j in failed:
                pat[j] = 0
            out.append(tuple(pat))
    return out


def default_max_failed(n_wheels: int) -> int | None:
    """Every pattern up to :data:`FULL_ENUMERATION_WHEELS` wheels, else :data:`MAX_FAILED` failed wheels at most."""
    return None if n_wheels <= FULL_ENUMERATION_WHEELS else MAX_FAILED


def pattern_controllability(
    chain: Chain, q: np.ndarray, eta: np.ndarray, k_v: float, max_failed: int | None = None
) -> list[dict]:
    """Rank of ctrb(A, B sigma) and the Gramian's smallest eigenvalue for every 0/1 pattern.

    ``A = -k_v I`` (the velocity loop closed by the dynamic law), ``B = Mbar1^-1 Bbar``
    at the state (q, eta); sorted from best to worst conditioned.  ``max_failed``: see
    :func:`fault_patterns`.  With A a multiple of the identity the Gramian has a closed form,
    ``W = int_0^inf e^(A t) B B^T e^(A^T t) dt = B B^T / (2 k_v)`` (the Lyapunov equation
    A W + W A^T + B B^T = 0), used here: exact, and no Lyapunov solve per pattern
    (``control.gram`` agrees to round-off, tests/test_analysis.py).  Raises ModelError when
    k_v is so small that W overflows.
    """
    Mbar1, _, _, Bbar = chain.reduced(q, eta)
    MB = np.linalg.solve(Mbar1, Bbar)
    A = -float(k_v) * np.eye(2)
    rows = []
    for pat in fault_patterns(chain.n_wheels, max_failed):
        B = MB * np.asarray(pat, dtype=float)[None, :]
        rank = int(np.linalg.matrix_rank(control.ctrb(A, B), tol=1e-9 * max(1.0, np.abs(MB).max())))
        # W = B B^T / (2 k_v): its smallest eigenvalue
        with np.errstate(over="ignore"):
            lam = float(np.linalg.eigvalsh(B @ B.T).min()) / (2.0 * float(k_v))
        if not math.isfinite(lam):
            raise ModelError(f"k_v = {k_v:g} 1/s: the controllability Gramian B B^T / (2 k_v) overflows")
        rows.append(
            {
                "pattern": list(pat),
                "rank": rank,
                "compensable_rule": pattern_is_compensable(pat),
                "gramian_min_eig": max(lam, 0.0),
            }
        )
    rows.sort(key=lambda r: -r["gramian_min_eig"])
    return rows


def _frozen_summary(times: np.ndarray, poles: np.ndarray) -> dict:
    """Frozen-time poles (samples x poles) as data: the worst real part, where, how often positive."""
    worst = poles.real.max(axis=1)
    k = int(np.argmax(worst))
    return {
        "times": times.tolist(),
        "worst_real_part": worst.tolist(),
        "worst": float(worst[k]),
        "t_worst": float(times[k]),
        "positive_fraction": float(np.mean(worst > 0)),
        "poles": [[[float(p.real), float(p.imag)] for p in row] for row in poles],
    }


def frozen_time_poles(
    ref: FlatReference, d: float, k1: float, k2: float, k3: float, k_v: float, duration: float, samples: int = 200
) -> dict:
    """Frozen-time poles of the two-link closed loop along a time-varying reference.

    At zero error the z-dynamics (3.19)-(3.22) keep their form with v_d(t), omega_d(t)
    (the derivative terms of f_alpha enter eta_c only and vanish in the Jacobian at
    z = 0), so the frozen-time Jacobian is :func:`two_link_error_jacobian` at
    (v_d(t), omega_d(t)).  Frozen-time stability does not prove stability of the
    time-varying loop; a positive real part flags where the design is fragile.
    """
    times = np.linspace(0.0, duration, samples)
    poles = []
    for t in times:
        r = ref.at(float(t))
        poles.append(np.linalg.eigvals(two_link_error_jacobian(d, r.v_d, r.omega_d, k1, k2, k3, k_v)))
    return _frozen_summary(times, np.array(poles))


def velocity_loop(
    chain: Chain, q: np.ndarray, eta: np.ndarray, k_v: float, law: np.ndarray, max_failed: int | None = None
) -> list[dict]:
    r"""Velocity loop of the law for pattern ``law`` against every true 0/1 pattern.

    With the minimum-norm law u = (MB sigma_k)^+ w on a plant with effectiveness sigma_a,
    eta_e' = -k_v G eta_e + (feedforward mismatch), G = MB sigma_a (MB sigma_k)^+
    = W_(a and k) W_k^-1 with W_p = MB sigma_p MB^T (MB = Mbar1^-1 Bbar).  G is a product
    of a positive semi-definite and a positive definite matrix: its eigenvalues are real,
    >= 0, and positive exactly when the wheels working in both patterns are compensable.
    Each eigen-direction is the loop L(s) = k_v lambda / s: python-control's
    stability_margins give its gain and phase margins (infinite and 90 deg while
    lambda > 0, whatever lambda: they are computed once, on the first stable pattern;
    the margin that matters is the rate k_v lambda_min).  ``max_failed``: see
    :func:`fault_patterns`.
    """
    Mbar1, _, _, Bbar = chain.reduced(q, eta)
    MB = np.linalg.solve(Mbar1, Bbar)
    law = np.asarray(law, dtype=float)
    Ak = MB * law[None, :]
    Wk = Ak @ Ak.T
    rows = []
    margins: tuple[float, float] | None = None  # of k_v lambda / s: the same for every lambda > 0
    for pat in fault_patterns(chain.n_wheels, max_failed):
        G = (MB * np.asarray(pat, float)[None, :]) @ np.linalg.solve(Wk, Ak).T
        lam = np.linalg.eigvals(G)
        lmin = float(lam.real.min())
        if lmin > 1e-12:
            if margins is None:
                margins = tuple(control.stability_margins(control.tf([k_v * lmin], [1, 0]))[:2])
            gm, pm = margins
        else:
            gm, pm = 0.0, 0.0
        rows.append(
            {
                "pattern": list(pat),
                "lambda_min": lmin,
                "rate": k_v * lmin,
                "stable": lmin > 1e-12,
                "gain_margin": float(gm),
                "phase_margin_deg": float(pm),
            }
        )
    return rows


# ---------------------------------------------------------------------- any closed loop, chained form
def central_jacobian(f, x0: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Jacobian of f at x0 by central differences of step h (error O(h^2))."""
    # column j: (f(x0 + h e_j) - f(x0 - h e_j)) / (2 h)
    return np.column_stack([(f(x0 + dx) - f(x0 - dx)) / (2 * h) for dx in h * np.eye(x0.size)])


def closed_loop_jacobian(chain: Chain, controller, t: float, q: np.ndarray, eta: np.ndarray, xc, h: float = 1e-6):
    r"""Jacobian of the closed loop (plant + controller with its discrete state xc held) in [q, eta].

    ``F(x) = [S(q) eta, etadot(q, eta, u(t, q, eta, xc))]`` by central differences of step h: the
    linearized tracking-error dynamics e' = A(t) e about the reference point (q_d(t), eta_d(t)).
    """
    p = chain.params
    N = chain.n_q
    x0 = np.concatenate((q, eta))

    def F(x):
        u, _ = controller.evaluate(t, x[:N], x[N:], xc)
        qd, ed = K.eta_dot(p, x[:N], x[N:], u)
        return np.concatenate((qd, ed))

    return central_jacobian(F, x0, h)


#: Chebyshev nodes of A(t) over the re-anchoring period (:func:`chained_circle_analysis`): 12, 16, 20 and 32
#: give the Floquet rate of the five- and six-robot circles within 4e-6 of RK4 on 960 steps of true Jacobians
CIRCLE_NODES = 16
#: the interpolated A(t) is trusted where it meets the frozen instants' Jacobians to this (relative, max
#: entry); farther off (a law not smooth over the period) the monodromy takes RK4 on true Jacobians
CIRCLE_FIT = 1e-4


def chained_circle_analysis(chain: Chain, kinematic, k_v: float, omega_d: float, steps: int = 480,
                            nodes: int = CIRCLE_NODES) -> dict:  # fmt: skip
    r"""Linearized chained-form closed loop on a constant-curvature reference (circle), healthy wheels.

    The chained form is expressed in a frame psi re-anchored to theta_nd each time |theta_nd - psi|
    reaches the band (ERRATA-free extension, see control.kinematic), so along a circle the error
    dynamics are not autonomous: between re-anchorings phi = theta_nd - psi sweeps [0, band] (sign
    of omega_d), and the loop is periodic up to a rotation of the plane.  Two results:

    * frozen-phi poles (the Jacobian at each phi): the pole loci over one period;
    * the Floquet multipliers of the period, from the monodromy of e' = A(t) e integrated over the
      period T = band / |omega_d| (RK4 on the matrix ODE, ``steps`` steps) and composed with the
      rotation R by the band (A(t + T) = R A(t) R^-1), giving the predicted convergence rate
      -ln rho(R^-1 Phi(T)) / T.

    A(t) is smooth over the period (phi sweeps [0, band] in one frame), so the monodromy integrates its
    interpolant at ``nodes`` Chebyshev points instead of a Jacobian at each RK4 stage (16 Jacobians
    instead of 121, issue 37 item 9).  Each Jacobian is a central difference of a law that itself
    differentiates eta_c (step 1e-5), so its entries carry about 1e-6 of noise: the interpolant meets the
    Jacobians between its nodes to that floor, and the rate agrees with RK4 on 960 steps of Jacobians
    within 4e-6 (the former RK4 on 60 steps of Jacobians: 4e-5 on the six-robot circle, 1e-5 on
    five_link_cascade).  Where the interpolant misses a frozen instant's Jacobian by more than
    ``CIRCLE_FIT``, RK4 takes the Jacobians themselves, 60 steps (a law not smooth over the period).
    """
    from ..control.tracking import TrackingController

    ref = kinematic.reference
    ctrl = TrackingController(chain, kinematic, k_v)
    r0 = ref.at(0.0)
    xc = kinematic.initial_state(0.0, r0.q_d)
    band = kinematic.band
    T = band / abs(omega_d)

    jacobians: dict[float, np.ndarray] = {}

    def A_at(t: float) -> np.ndarray:
        # each instant once (the frozen instants are also the interpolant's checks; with RK4 on the
        # Jacobians themselves a step's end t + h is the next step's start, the same float)
        if t not in jacobians:
            r = ref.at(t)
            jacobians[t] = closed_loop_jacobian(chain, ctrl, t, r.q_d, r.eta_d, xc)
        return jacobians[t]

    m = chain.n_q + 2
    frozen = []
    for t in np.linspace(0.0, T, 7):
        ev = np.linalg.eigvals(A_at(float(t)))
        ev = ev[np.argsort(-ev.real)]
        frozen.append({"phi_deg": math.degrees(omega_d * t), "poles": [[float(z.real), float(z.imag)] for z in ev]})
    Phi = _monodromy(A_at, T, steps, nodes, [float(t) for t in np.linspace(0.0, T, 7)])
    R = np.eye(m)
    c, s = math.cos(math.copysign(band, omega_d)), math.sin(math.copysign(band, omega_d))
    R[:2, :2] = [[c, -s], [s, c]]
    mu = np.linalg.eigvals(np.linalg.solve(R, Phi))
    rho = float(np.abs(mu).max())
    return {
        "period": T,
        "frozen": frozen,
        "multipliers": [[float(z.real), float(z.imag)] for z in mu[np.argsort(-np.abs(mu))]],
        "floquet_rate": -math.log(rho) / T,
        "worst_frozen_real_part": max(f["poles"][0][0] for f in frozen),
    }


def _monodromy(A_at, T: float, steps: int, nodes: int, checks: list[float]) -> np.ndarray:
    """Phi(T) of Phi' = A(t) Phi, Phi(0) = I, by RK4: on A's Chebyshev interpolant, or on A_at itself
    (60 steps) where the interpolant misses A_at at ``checks`` (instants already computed) by more than
    CIRCLE_FIT."""
    from numpy.polynomial import chebyshev

    # nodes x_k = cos(pi (k + 1/2) / K) on [-1, 1], t = T (1 + x) / 2
    x = np.cos(np.pi * (np.arange(nodes) + 0.5) / nodes)
    As = np.array([A_at(float(T * (1.0 + xk) / 2.0)) for xk in x])
    m = As.shape[1]
    coef = chebyshev.chebfit(x, As.reshape(nodes, -1), nodes - 1)

    def fitted(ts) -> np.ndarray:
        return chebyshev.chebval(2.0 * np.asarray(ts) / T - 1.0, coef).T.reshape(-1, m, m)

    known = np.array([A_at(t) for t in checks])
    miss = float(np.abs(fitted(checks) - known).max() / max(float(np.abs(known).max()), 1e-300))
    if miss > CIRCLE_FIT:
        steps, grid = 60, None
    else:
        h = T / steps
        # A at the steps' starts, middles and ends: one evaluation of the interpolant
        grid = fitted(h * np.arange(2 * steps + 1) / 2.0)
    Phi = np.eye(m)
    h = T / steps
    t = 0.0
    for k in range(steps):
        if grid is None:
            A1, A2, A4 = A_at(t), A_at(t + h / 2), A_at(t + h)
        else:
            A1, A2, A4 = grid[2 * k], grid[2 * k + 1], grid[2 * k + 2]
        k1 = A1 @ Phi
        k2 = A2 @ (Phi + h / 2 * k1)
        k3 = A2 @ (Phi + h / 2 * k2)
        k4 = A4 @ (Phi + h * k3)
        Phi = Phi + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += h
    return Phi


def chained_frozen_time_poles(chain: Chain, kinematic, k_v: float, duration: float, samples: int = 120) -> dict:
    """Frozen-time poles of the chained-form closed loop along any reference (healthy wheels).

    At each sample time the Jacobian :func:`closed_loop_jacobian` at the reference point, with the
    frame psi the controller would hold then (re-anchored along the reference by the controller's
    own rule).  Indicative only, as for the two-link loop: frozen-time stability is not a proof.
    """
    from ..control.tracking import TrackingController

    ctrl = TrackingController(chain, kinematic, k_v)
    ref = kinematic.reference
    times = np.linspace(0.0, duration, samples)
    xc = kinematic.initial_state(0.0, ref.at(0.0).q_d)
    poles = []
    for t in times:
        r = ref.at(float(t))
        xc = kinematic.discrete(float(t), r.q_d, xc)
        ev = np.linalg.eigvals(closed_loop_jacobian(chain, ctrl, float(t), r.q_d, r.eta_d, xc))
        poles.append(ev[np.argsort(-ev.real)])
    return _frozen_summary(times, np.array(poles))


def scheme_gain(case, scheme: str) -> float:
    """The velocity gain k_v a scheme of the case runs with (a plug-in without one: the case's default)."""
    from ..evaluation.families import default_k_v

    k_v = getattr(getattr(case.schemes, scheme, None), "k_v", None)
    return float(default_k_v(case) if k_v is None else k_v)


def _omega(case) -> float:
    r = case.reference
    if r.kind == "unicycle":
        return float(r.omega_d)
    if r.kind == "circle":
        return (1.0 if r.ccw else -1.0) * float(r.speed) / float(r.radius)
    return 0.0


def _chained(case, chain: Chain, ref: FlatReference):
    from ..control.kinematic import ChainedBackstepping

    k = case.kinematic
    c = k.c_chain if isinstance(k.c_chain, list) else [k.c_chain] * chain.n
    return ChainedBackstepping(chain.d, ref, c, k.c_alpha2, k.c_xi1, k.kappa, band=math.radians(k.band_deg), mu=k.mu)


# ---------------------------------------------------------------------- observer
def measured_q_model(chain: Chain, q: np.ndarray, eta: np.ndarray, u: np.ndarray, h: float = 1e-6):
    r"""Linearization of the plant with parameters as constant states, output y = q.

    State ``[q, eta, rho, ubar]`` (N + 2 + 4n), ``rho' = ubar' = 0``; central-difference Jacobian of
    ``q' = S(q) eta``, ``eta' = Mbar1^-1 (-Mbar2 eta - Cbar + Bbar (diag(rho) u + ubar))`` (2.70, 2.102)
    at healthy parameters.  Returns (A, C) as arrays.
    """
    p = chain.params
    N, nw = chain.n_q, chain.n_wheels

    def f(x):
        qx, ex = x[:N], x[N : N + 2]
        rho, ubar = x[N + 2 : N + 2 + nw], x[N + 2 + nw :]
        qd, ed = K.eta_dot(p, qx, ex, rho * u + ubar)
        return np.concatenate((qd, ed, np.zeros(2 * nw)))

    x0 = np.concatenate((q, eta, np.ones(nw), np.zeros(nw)))
    return central_jacobian(f, x0, h), np.eye(N, x0.size)


def observability(chain: Chain, q: np.ndarray, eta: np.ndarray, u: np.ndarray) -> dict:
    """Ranks of ``control.obsv`` for the measured-q model: the state alone, and with the 4n parameters.

    The state [q, eta] is observable (rank N + 2: qdot = S eta with S of full column rank).  With the
    gains and frictions appended, the rank at a frozen instant is N + 2 + rank(Mbar1^-1 Bbar [diag(u), I])
    <= N + 4: only two combinations of the 4n parameters are seen at each instant (ERRATA P3); the rest
    must come from the variation of u along the motion.
    """
    A, C = measured_q_model(chain, q, eta, u)
    N = chain.n_q
    ns = N + 2
    Os = control.obsv(A[:ns, :ns], C[:, :ns])
    Oa = control.obsv(A, C)
    sv = np.linalg.svd(Oa, compute_uv=False)
    tol = sv[0] * 1e-9
    return {
        "state_dim": ns,
        "state_rank": int(np.linalg.matrix_rank(Os, tol=np.linalg.svd(Os, compute_uv=False)[0] * 1e-9)),
        "augmented_dim": A.shape[0],
        "augmented_rank": int(np.sum(sv > tol)),
    }


def farza_error_poles(Theta: float, n_q: int, k0: float = 1.0, k1: float = 1.0) -> np.ndarray:
    r"""Poles of the Farza observer's linearized state-error dynamics (parameters known, model part omitted).

    With K(e) ~ k0 k1 e near 0 and the gain Theta Delta^-1 S_o^-1 C^T = [2 Theta I; Theta^2 I], each
    coordinate's error pair obeys e1' = e2 - 2 Theta k e1, e2' = -Theta^2 k e1 (k = k0 k1): characteristic
    polynomial s^2 + 2 Theta k s + Theta^2 k, poles Theta (-k +/- sqrt(k^2 - k)), proportional to Theta
    (a double pole at -Theta for k = 1).  Built as a ``control.ss`` and read with ``poles()``.
    """
    k = k0 * k1
    I = np.eye(n_q)
    Z = np.zeros((n_q, n_q))
    A = np.block([[-2 * Theta * k * I, I], [-(Theta**2) * k * I, Z]])
    return np.sort_complex(control.ss(A, np.zeros((2 * n_q, 1)), np.eye(1, 2 * n_q), 0).poles())


def farza_linearized_poles(obs, q: np.ndarray, qdot: np.ndarray, u: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Poles of the full observer's state-error dynamics at zero error (model Jacobian included).

    Central-difference Jacobian of the observer's xhat derivative with respect to xhat, the measured
    q and the parameter estimates held (at the truth, healthy).  For large Theta the poles approach
    :func:`farza_error_poles`; for small Theta the model's own dynamics shift them.
    """
    s0 = obs.initial_state(q, qdot)
    n = 2 * obs.N

    def f(xhat):
        s = s0.copy()
        s[:n] = xhat
        return obs.derivative(u, q, s)[:n]

    return np.sort_complex(np.linalg.eigvals(central_jacobian(f, s0[:n], h)))


def healthy_torque(p, q: np.ndarray, eta: np.ndarray, etadot_des: np.ndarray) -> np.ndarray:
    """Minimum-norm torques realising etadot_des with healthy wheels, (2n,): the operating point's input.

    The healthy instance of (3.35): ``u = (Mbar1^-1 Bbar)^+ [etadot_des + Mbar1^-1 (Mbar2 eta + Cbar)]``
    (= Bbar^+ (Mbar1 etadot_des + Mbar2 eta + Cbar): both matrices have the same row space), the
    pseudo-inverse the compiled law's (``control.tracking.law_for_pattern``).
    """
    from ..control.tracking import LawTerms, law_for_pattern

    Mbar1, Mbar2, Cbar, Bbar = K.reduced(p, q, eta)
    MB = np.linalg.solve(Mbar1, Bbar)
    w = np.asarray(etadot_des, dtype=float) + np.linalg.solve(Mbar1, Mbar2 @ eta + Cbar)
    return law_for_pattern(LawTerms(w, MB, np.zeros(2)), np.ones(Bbar.shape[1]))


def observer_analysis(chain: Chain, q: np.ndarray, eta: np.ndarray, u: np.ndarray, thetas=(0.5, 0.9, 1.6, 3.0, 6.0)):
    """Observability ranks and Farza error poles against Theta at one operating point, as data."""
    from ..observers import FarzaObserver

    qdot = chain.S(q) @ eta
    rows = []
    for th in thetas:
        obs = FarzaObserver(chain, th, p_max=1e3)
        full = farza_linearized_poles(obs, q, qdot, u)
        nominal = farza_error_poles(th, chain.n_q)
        rows.append(
            {
                "Theta": th,
                "nominal_poles": [[float(z.real), float(z.imag)] for z in nominal],
                "slowest_nominal": float(-nominal.real.max()),
                "slowest_full": float(-full.real.max()),
                "fastest_full": float(-full.real.min()),
            }
        )
    return {"observability": observability(chain, q, eta, u), "farza_poles": rows}


def classic_analyses(case) -> dict:
    """The analyses of one validated case that need no scheme's own law, as plain data.

    ``closed_loop_poles`` (per built-in scheme, [re, im] pairs) is given for two-link cases on a
    constant-velocity unicycle reference: at zero error with healthy wheels every built-in scheme
    applies the same matched law, so their poles coincide; chained-form cases on a circle get the
    frozen poles over the re-anchoring period and the Floquet rate, time-varying references the
    frozen-time poles.  Controllability per pattern, the healthy law's velocity loop and the observer
    use the gain of the first scheme the case runs (a plug-in's own ``k_v`` when that is all it runs).
    Every scheme in every fault phase, in discrete time where sampled: :func:`ftcreport.analysis.analyze_case`.
    """
    from ..cases import SCHEME_NAMES, build_chain, configured_schemes

    out: dict = {"case": case.name, "n_robots": case.robots.n, "reference_kind": case.reference.kind}
    chain = build_chain(case)
    ref = FlatReference(case.reference.path(), chain.d)
    kin = case.kinematic
    schemes = [s for s in SCHEME_NAMES if getattr(case.schemes, s) is not None]
    k_v0 = scheme_gain(case, configured_schemes(case)[0])  # the first scheme's gain (frozen-time poles, patterns)
    if kin.kind == "two_link" and case.reference.kind == "unicycle":
        v_d, w_d = case.reference.v_d, case.reference.omega_d
        out["kinematic_poles"] = pole_table(kinematic_error_matrix(v_d, w_d, kin.k1, kin.k2, kin.k3))
        out["closed_loop_poles"] = {}
        out["pole_tables"] = {}
        for s in schemes:
            k_v = getattr(case.schemes, s).k_v
            table = pole_table(two_link_error_jacobian(chain.d[0], v_d, w_d, kin.k1, kin.k2, kin.k3, k_v))
            out["pole_tables"][s] = table
            out["closed_loop_poles"][s] = [[r["re"], r["im"]] for r in table]
            out["predicted_decay_rate"] = -table[0]["re"]
    elif kin.kind == "two_link":
        out["closed_loop_poles"] = None
        out["note"] = "time-varying reference: see the frozen-time poles"
        out["frozen_time"] = frozen_time_poles(ref, chain.d[0], kin.k1, kin.k2, kin.k3, k_v0, case.simulation.duration)
    elif case.reference.kind in ("circle", "unicycle") and _omega(case) != 0.0:
        # chained form on a constant-curvature reference: frozen poles over the re-anchoring period
        # and the Floquet rate of the period (the same for every scheme at zero error, healthy wheels)
        out["closed_loop_poles"] = {}
        out["chained"] = {}
        by_gain: dict[float, dict] = {}
        for s in schemes:
            k_v = getattr(case.schemes, s).k_v
            if k_v not in by_gain:
                by_gain[k_v] = chained_circle_analysis(chain, _chained(case, chain, ref), k_v, _omega(case))
            res = by_gain[k_v]
            out["chained"][s] = res
            out["closed_loop_poles"][s] = res["frozen"][0]["poles"]
            out["predicted_decay_rate"] = res["floquet_rate"]
    else:
        out["closed_loop_poles"] = None
        out["note"] = "time-varying reference: see the frozen-time poles"
        span = min(case.simulation.duration, 60.0)
        try:
            out["frozen_time"] = chained_frozen_time_poles(chain, _chained(case, chain, ref), k_v0, span, samples=60)
        except FtcError as exc:  # the law is singular on the reference itself: say so, do not crash the page
            out["frozen_time"] = None
            out["note"] = f"frozen-time poles not computed: the law is singular on the reference ({exc})"
    q0 = ref.at(0.0).q_d
    mf = default_max_failed(chain.n_wheels)
    out["patterns_enumerated"] = {
        "max_failed": mf,
        "count": len(fault_patterns(chain.n_wheels, mf)),
        "total": 2**chain.n_wheels,
        "compensable_total": 3 * 2 ** (chain.n_wheels - 2) - 2,  # the rule of (2.103), ftcreport patterns
    }
    try:
        out["controllability"] = pattern_controllability(chain, q0, ref.at(0.0).eta_d, k_v0, mf)
    except FtcError as exc:  # an absurd gain: say so on the page, do not crash it
        out["controllability"] = []
        out["note"] = (out.get("note", "") + f"; controllability not computed: {exc}").lstrip("; ")
    # passive robustness of the healthy (nominal) law: the true patterns it keeps stable, and how fast
    vl = velocity_loop(chain, q0, ref.at(0.0).eta_d, k_v0, np.ones(chain.n_wheels), mf)
    stable = [r for r in vl if r["stable"]]
    out["nominal_velocity_loop"] = {
        "enumerated_patterns": len(vl),
        "stable_patterns": len(stable),
        "compensable_patterns": sum(pattern_is_compensable(r["pattern"]) for r in vl),
        "slowest_rate": min(r["rate"] for r in stable),
        "rows": vl,
    }
    if case.schemes.active is not None or case.schemes.active_ukf is not None:
        # operating point: the reference at t = 0 with the healthy torque that realizes it
        r0 = ref.at(0.0)
        u0 = healthy_torque(chain.params, r0.q_d, r0.eta_d, r0.eta_d_dot)
        thetas = sorted({0.5, 1.0, 2.0, 4.0, *([case.schemes.active.Theta] if case.schemes.active else [])})
        out["observer"] = observer_analysis(chain, r0.q_d, r0.eta_d, u0, thetas)
    return out
