r"""Passive FTC 1: multiple dynamic controllers and a switching mechanism.

Thesis sections 3.2.2.2-3.2.2.3 and 3.3.1 (3.33-3.48, 3.107), ERRATA E8, E12f, E12g.

* One dynamic law per failure pattern sigma_(k) (3.35)/(3.107), all sharing the
  kinematic controller; only the selected one is applied.
* Reconstruction filters, one per model (3.42)::

      etahat_(k) = gamma/(s+gamma)[eta] + 1/(s+gamma)[-Mbar1^-1 (Mbar2 eta + Cbar)]
                   + 1/(s+gamma)[Mbar1^-1 Bbar sigma_(k) u]

  i.e. ``etahat_(k)' = -gamma etahat_(k) + gamma eta - Mbar1^-1 (Mbar2 eta + Cbar)
  + Mbar1^-1 Bbar sigma_(k) u`` with the applied u, started at etahat_(k)(0) = eta(0)
  (ERRATA E12g).  The matched model then reconstructs exactly: its error obeys
  e' = -gamma e + Mbar1^-1 Bbar (sigma - sigma_(k)) u = -gamma e.
  The filters are linear in sigma_(k), so they are run by superposition (issue 20 item 5):
  the healthy model's filter h and one filter z_j per wheel, ``etahat_(k) = h - sum_j (1 - sigma_kj) z_j``;
  2 + 4n states for the whole bank instead of 2 N (control.switching_compiled.switching_rates).
* Costs (3.46), with the optional forgetting integral of Narendra & Balakrishnan
  (1994): ``J_(k) = c_inst |etatilde_(k)|^2 + c_int int_0^t exp(-lambda (t - s)) |etatilde_(k)(s)|^2 ds``;
  the integral is ``I' = -lambda I + |etatilde|^2`` per model; superposed, it is the quadratic form
  ``(1, f_k)^T M (1, f_k)`` of one (2n + 1)^2 symmetric matrix M (f_k = 1 - sigma_(k)).
  The thesis uses c_inst = 1, c_int = 0.
* Switching (3.47)-(3.48), after every integration step: the argmin of J is
  applied if at least T_min has passed since the last switch.  Hysteresis
  (ours, ERRATA E12g): a candidate replaces the applied model only if its cost is
  lower by more than ``hysteresis`` (absolute).  The laws of models that differ
  only in wheels the applied law sends no torque to reconstruct identically, so
  their costs tie at round-off level; without the margin argmin + T_min chatters
  among them.  Ties resolve to the lowest index: patterns are ordered healthy
  first, then by number of assumed failures.  A tie is a cost within
  ``TIE_RTOL`` (relative) of the smallest: round-off (about 1e-13 here) must not
  decide between models that are equivalent, or the run depends on the order of
  floating-point operations (another BLAS, another compiler) from the first such
  tie on.

* The least cost is found without visiting every model (control.switching_compiled._walk: a depth-first walk over
  the wheels that skips the subtrees whose lower bound cannot win), so n = 8 (49,150 models) runs
  in real time; the chosen model is the exhaustive rule's (tests/test_switching_bank.py).

The controller's state is ``[kinematic state, h (2), z_1 .. z_2n (2 each), M's upper triangle
((2n + 1)(2n + 2) / 2, if c_int > 0), selected index, time of the last switch]``; the last two are
discrete (zero derivative, changed only by :meth:`discrete`).  The equations are the compiled
kernels' (control.switching_compiled.switching_rates, switching_select, switching_costs), called from here too.

Logged signals: ``selected`` and, for banks of at most :data:`MAX_LOGGED_COSTS` models, ``cost``
(every model's J, (N,) per sample); larger banks log ``cost_selected`` (the applied model's J) and
``cost_best`` (the least J of the bank) instead.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ModelError
from ..model.chain import Chain
from ..model.faults import model_patterns
from ..schemes.controller import SchemeController
from .kinematic import ChainedBackstepping, TwoLinkKinematic

__all__ = ["MAX_LOGGED_COSTS", "TIE_RTOL", "SwitchingController"]

TIE_RTOL = 1e-9  # switching costs this close (relative) to the smallest are ties
MAX_LOGGED_COSTS = 4096  # banks up to this size log every model's cost (n <= 6 with every pattern)
WALK_MIN_MODELS = 32  # 0/1 banks from this size on are searched by the walk (control.switching_compiled._walk)


class SwitchingController(SchemeController):
    """Multiple-model switching FTC for any n with either kinematic controller: the switching scheme's face.

    Parameters
    ----------
    chain : Chain
        The controller's model.
    kinematic : TwoLinkKinematic or ChainedBackstepping
    k_v : float
        Velocity-error gain of every dynamic law (thesis k4 / c6).
    patterns : sequence of 0/1 sequences, optional
        The failure patterns sigma_(k) (1 = wheel works); default: every
        compensable pattern of the chain.
    gamma : float
        Pole of the reconstruction filters 1/(s + gamma) [1/s].
    T_min : float
        Waiting time between two switches [s].
    c_inst, c_int, forgetting : float
        Cost weights and forgetting rate lambda [1/s] of the integral term.
    hysteresis : float
        Absolute cost margin [(m/s)^2] a candidate must win by.
    u_limit : float, optional
        Saturation of the plant's actuators, if known: the filters use the
        saturated signal.
    initial_model : int
        Index of the model applied at the start (0: the first pattern).
    rotor_inertia : (2n,) array_like, optional
        The DC motors' rotor inertia on each wheel axis, eta_g N^2 J_m [kg m^2] (ERRATA E19): the
        filters (3.42) predict eta with it (control.switching_compiled.rotor_filter_terms); the law keeps the
        chain's model.  None: the chain alone (no motors, or a bank that ignores them).
    """

    def __init__(
        self,
        chain: Chain,
        kinematic: TwoLinkKinematic | ChainedBackstepping,
        k_v: float,
        patterns: Sequence[Sequence[float]] | None = None,
        gamma: float = 10.0,
        T_min: float = 0.01,
        c_inst: float = 1.0,
        c_int: float = 0.0,
        forgetting: float = 1.0,
        hysteresis: float = 1e-10,
        u_limit: float | None = None,
        initial_model: int = 0,
        rotor_inertia: Sequence[float] | None = None,
    ) -> None:
        pats = model_patterns(chain.n, patterns)
        for name, val in (("gamma", gamma), ("forgetting", forgetting)):
            if not val > 0:
                raise ModelError(f"{name}: must be > 0, got {val}")
        if T_min < 0 or c_inst < 0 or c_int < 0 or hysteresis < 0:
            raise ModelError("T_min, c_inst, c_int and hysteresis must be >= 0")
        from ..schemes import get

        self._bind(get("switching"), chain, kinematic, k_v, saturation=u_limit)
        self.patterns = np.array(pats, dtype=float)  # (N, 2n)
        self.N = self.patterns.shape[0]
        self.gamma, self.T_min = float(gamma), float(T_min)
        self.c_inst, self.c_int, self.forgetting = float(c_inst), float(c_int), float(forgetting)
        self.hysteresis = float(hysteresis)
        self.rotor_inertia = None if rotor_inertia is None else np.asarray(rotor_inertia, dtype=float).reshape(-1)
        if self.rotor_inertia is not None and self.rotor_inertia.shape != (chain.n_wheels,):
            raise ModelError(f"rotor_inertia: {chain.n_wheels} values (one per wheel) expected")
        if not 0 <= int(initial_model) < self.N:
            raise ModelError(f"initial_model: {initial_model} is not a model index (0..{self.N - 1})")
        self.initial_model = int(initial_model)
        nk = kinematic.n_states
        nw = chain.n_wheels
        n_tri = (nw + 1) * (nw + 2) // 2
        self._kin = slice(0, nk)
        self._filt = slice(nk, nk + 2 + 2 * nw)  # h, z_1 .. z_2n
        self._int = slice(self._filt.stop, self._filt.stop + (n_tri if self.c_int > 0 else 0))
        self._sel = self._int.stop
        self._tsw = self._sel + 1
        self.n_own = self._tsw + 1 - nk
        self.widths = {}
        self.log_costs = self.N <= MAX_LOGGED_COSTS
        self._packed = None
        # exact diagonal Jacobian of the linear filter / integral states (used by ROS2)
        stiff = np.zeros(self._tsw + 1)
        stiff[self._filt] = -self.gamma
        stiff[self._int] = -self.forgetting
        self._finish(stiff[nk:])

    # ------------------------------------------------------------------ helpers
    def walk_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """(codes, trie) of the walk (jit.packed.Law), or empty arrays when every pattern is evaluated.

        codes[sum_j sigma_j 2^j] is the bank index of a 0/1 pattern (-1: not in the bank);
        trie[2^d + (code mod 2^d)] is 1 when a bank pattern starts with those d wheels; trie[0] is 1
        when the bank is monotone (each pattern with one more working wheel is in it, at a lower index).
        """
        nw = self.chain.n_wheels
        P = self.patterns
        if self.N < WALK_MIN_MODELS or nw > 30 or not np.all((P == 0.0) | (P == 1.0)):
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint8)
        code = (P.astype(np.int64) << np.arange(nw, dtype=np.int64)[None, :]).sum(axis=1)
        codes = np.full(1 << nw, -1, dtype=np.int64)
        codes[code[::-1]] = np.arange(self.N, dtype=np.int64)[::-1]  # a repeated pattern: its first index
        trie = np.zeros(1 << (nw + 1), dtype=np.uint8)
        for d in range(nw + 1):
            trie[(1 << d) + (code & ((1 << d) - 1))] = 1
        # monotone: each pattern with one more working wheel is in the bank at a lower index
        idx = np.arange(self.N, dtype=np.int64)
        up = code[:, None] | (np.int64(1) << np.arange(nw, dtype=np.int64))[None, :]  # (N, nw)
        ok = (codes[up] >= 0) & (codes[up] < idx[:, None])
        trie[0] = np.all(ok | (P == 1.0))
        return codes, trie

    def packed(self):
        """The kernels' parameters (jit.packed.Law): the bank, the superposed filters' layout (offsets in
        the scheme's own states, after the kinematic controller's) and the walk's tables
        (control.switching_compiled.switching_rates, switching_select), built once."""
        if self._packed is None:
            from ..jit.packed import LAW_SWITCHING, law_params

            codes, trie = self.walk_tables()
            nk = self.kin.n_states
            self._packed = law_params(
                LAW_SWITCHING, self.k_v, self.chain.n_wheels, self.n_states,
                patterns=np.ascontiguousarray(self.patterns, dtype=float), gamma=self.gamma, T_min=self.T_min,
                c_inst=self.c_inst, c_int=self.c_int, forgetting=self.forgetting, hysteresis=self.hysteresis,
                u_limit=float("nan") if self.u_limit is None else float(self.u_limit), hat0=self._filt.start - nk,
                int0=self._int.start - nk, n_int=self._int.stop - self._int.start, sel=self._sel - nk,
                tsw=self._tsw - nk, codes=codes, trie=trie,
                Jw=np.zeros(0) if self.rotor_inertia is None else self.rotor_inertia,
            )  # fmt: skip
        return self._packed

    @property
    def P(self):
        return self.packed()

    def costs(self, eta: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """J_(k) for every model, (N,), at the controller state ``xc`` (control.switching_compiled.switching_costs)."""
        from .switching_compiled import switching_costs

        own = np.asarray(xc, dtype=float)[self.kin.n_states :]
        return switching_costs(self.packed(), np.ascontiguousarray(eta, dtype=float), own)

    def filters(self, xc: np.ndarray) -> np.ndarray:
        """etahat_(k) of every model, (N, 2): h - sum_j (1 - sigma_kj) z_j."""
        nw = self.chain.n_wheels
        f = xc[self._filt]
        return f[None, :2] - (1.0 - self.patterns) @ f[2:].reshape(nw, 2)

    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        xc = np.zeros(self.n_states)
        xc[self._kin] = self.kin.initial_state(t, q)
        xc[self._filt.start : self._filt.start + 2] = eta  # etahat_(k)(0) = eta(0), ERRATA E12g; z_j(0) = 0
        xc[self._sel] = float(self.initial_model)
        xc[self._tsw] = -1e9  # "long ago" (finite: the engine rejects non-finite states)
        return xc
