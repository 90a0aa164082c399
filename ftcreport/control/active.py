r"""Active FTC: an estimator of velocities and actuator faults, and a law that uses the estimates.

Thesis section 4.2.3, (4.12)-(4.14).  Only q is measured: the velocity eta
the engine also hands over is ignored.  With the estimator's q_hat, eta_hat,
rho_hat, ubar_hat, the dynamic law (4.14) is::

    u = (Mbar1^-1 Bbar sigma_hat)^+ [ -k_v etahat_e - T_alpha^T f_eta + Mbar1^-1 (Mbar2 etahat + Cbar)
                                      - Mbar1^-1 Bbar ubar_hat + etadot_c ]

with etahat_e = etahat - eta_c, the matrices evaluated at the measured q and
etahat, eta_c from the kinematic law (4.12) at the measured q, and etadot_c
the directional derivative along qdot = S(q) etahat (ERRATA P5).  Choices
where the thesis is silent or ambiguous:

* sigma_hat = clip(rho_hat, 0, 1): a gain estimate outside [0, 1] is not a
  physical effectiveness (the issue asks for the clip);
* the friction estimate used by the law is clipped to the actuator limit: a
  friction beyond it cannot be compensated by any admissible u, and such values
  occur only in the estimator's transients after a fault (ERRATA P3);
* optional first-order filters 1/(tau s + 1) on rho_hat and ubar_hat before the
  law (thesis 4.2.4, tau = 30 s in the three-link case), started at the
  nominal values;
* the control is clipped to the actuator limit, and the estimator is given the
  clipped value (what the motors actually receive);
* a continuous estimator (Farza) is integrated with the plant; a discrete one
  (the UKF) runs at the sampling instants and the control is then held over
  the sample (a sampled-data controller: measure, update, compute, hold).

State: ``[kinematic state, estimator state, filtered rho and ubar (if tau),
held u and the last sample time (discrete estimators)]``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ModelError
from ..model.chain import Chain
from ..schemes.controller import SchemeController
from .kinematic import ChainedBackstepping, TwoLinkKinematic

__all__ = ["ActiveController"]


class ActiveController(SchemeController):
    """Estimator-based active FTC for any n with either kinematic controller: the face of the ``active``
    (Farza observer) and ``active_ukf`` (UKF) schemes.

    Parameters
    ----------
    chain : Chain
        The controller's (and estimator's) model.
    kinematic : TwoLinkKinematic or ChainedBackstepping
    k_v : float
        Velocity-error gain (thesis k4 / c6).
    estimator : FarzaObserver or UKFEstimator
    u_limit : float, optional
        Actuator limit [N m] (thesis 5 N m); the estimator receives the clipped control.
    tau : float, optional
        Time constant [s] of the filters on the estimates (thesis 30 s); None: unfiltered.
    """

    def __init__(
        self,
        chain: Chain,
        kinematic: TwoLinkKinematic | ChainedBackstepping,
        k_v: float,
        estimator,
        u_limit: float | None = None,
        tau: float | None = None,
    ) -> None:
        if tau is not None and not tau > 0:
            raise ModelError(f"tau: filter time constant must be > 0 s, got {tau}")
        if u_limit is not None and not u_limit > 0:
            raise ModelError(f"u_limit: must be > 0 N m, got {u_limit}")
        from ..schemes import get

        self._bind(get(estimator.scheme), chain, kinematic, k_v, saturation=u_limit)
        self.est = estimator
        self.tau = tau
        self.discrete_time = bool(estimator.discrete_time)
        nw = chain.n_wheels
        nk = kinematic.n_states
        self._kin = slice(0, nk)
        self._est = slice(nk, nk + estimator.n_states)
        self._filt = slice(self._est.stop, self._est.stop + (2 * nw if tau is not None else 0))
        self._u = slice(self._filt.stop, self._filt.stop + (nw if self.discrete_time else 0))
        self._t = slice(self._u.stop, self._u.stop + (1 if self.discrete_time else 0))
        self.n_own = self._t.stop - nk
        nq = chain.n_q
        self.widths = {"q_hat": nq, "eta_hat": 2, "rho_hat": nw, "ubar_hat": nw, "sigma_used": nw, "ubar_used": nw}
        self._P = None
        self._finish()

    @property
    def P(self):
        """The compiled law's parameters (control.active_law.Active; offsets in the scheme's own states)."""
        if self._P is None:
            from ..jit.packed import LAW_ACTIVE, law_params
            from ..model.kernels import packed
            from .active_law import active

            nk = self.kin.n_states
            nan = float("nan")
            law = law_params(
                LAW_ACTIVE, self.k_v, self.chain.n_wheels, self.n_states,
                u_limit=nan if self.u_limit is None else float(self.u_limit),
            )  # fmt: skip
            pc = packed(self.chain.params)
            if self.discrete_time:
                from ..observers.ukf_compiled import UkfLaw, ukf_params

                o = self.est
                ukf = UkfLaw(
                    law, ukf_params(o), packed(o.chain.params), self._est.start - nk, self._filt.start - nk,
                    nan if self.tau is None else float(self.tau), self._u.start - nk, self._t.start - nk,
                )  # fmt: skip
                self._P = active(law, pc, ukf=ukf)
            else:
                obs = self.est.packed(tau=self.tau, est0=self._est.start - nk, filt0=self._filt.start - nk)
                self._P = active(law, pc, obs=obs)
        return self._P

    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        xc = np.zeros(self.n_states)
        xc[self._kin] = self.kin.initial_state(t, q)
        xc[self._est] = self.est.initial_state(q)  # only q is measured: velocity estimate starts at 0
        if self.tau is not None:
            nw = self.chain.n_wheels
            xc[self._filt] = np.concatenate((np.ones(nw), np.zeros(nw)))
        if self.discrete_time:  # the engine's discrete update computes the first command at t0 (observers.ukf_compiled)
            xc[self._t] = t
        return xc
