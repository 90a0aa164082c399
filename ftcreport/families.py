r"""Every FTC family on every case: default scheme tables, and why a family cannot apply (pure).

A case runs :data:`FAMILIES` (nominal, switching, adaptive, active with the Farza observer,
active with the UKF, oracle) unless its file narrows the list with ``schemes.run``.  A family
whose table the file does not give gets the defaults below; a table the file gives is kept as
written.  ``adaptive_frozen`` (an ablation of the adaptive law) runs only when its table is given.

Defaults (thesis values; cases/README.md documents them):

* ``k_v``: ``schemes.k_v`` if given, else the ``k_v`` of the first table the file gives (in the
  order of :data:`ftcreport.cases.SCHEME_NAMES`), else 10 for the two-link controller (3.3.2.3,
  eight: k4 = 10) and 2 for the chained form (3.3.1.4 and 3.3.2.3: c6 = 2).
* switching: gamma = 10, T_min = 0.01 s (3.2.3); the adaptive table's patterns if it narrows
  them, else every compensable pattern.
* adaptive: gamma = 1, Gamma_f = 1 (3.3.2.3); the switching table's patterns if it narrows them,
  else every compensable pattern.
* active (Farza): Theta = 1.6 for the two-link controller (Table 4.1) and 0.9 for the chained
  form (Table 4.2), k0 = k1 = 1, P(0) = 0.1 I (4.2.4); P guard 1e3; gains and frictions estimated.
* active_ukf: the schema's defaults; ``meas_std`` the plant's sensor noise when it has one.

Cannot apply (:func:`not_applicable`): the UKF runs at the samples and holds its control over
each step of length dt, so the velocity error obeys e_(k+1) = (1 - k_v dt) e_k: the sampled loop
is unstable when k_v dt >= 2 (e.g. the thesis's k4 = 3000 at dt = 5 ms gives 15).  A default
UKF table is not added then, and the reason is given instead of a run.  Likewise the default
active (Farza) table when k_v / Theta > 100: the law closes a k_v-fast velocity loop on an observer
of rate Theta (measured: k_v / Theta = 12.5 and 5.6 in Tables 4.1 and 4.2 track; 1875, the
thesis's k4 = 3000 of 3.2.3, diverges within 10 ms).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from .cases import Case

__all__ = ["FAMILIES", "KV_THESIS", "default_k_v", "fill_defaults", "not_applicable"]

FAMILIES = ("nominal", "switching", "adaptive", "active", "active_ukf", "oracle")
KV_THESIS = {"two_link": 10.0, "chained": 2.0}
THETA_THESIS = {"two_link": 1.6, "chained": 0.9}
SAMPLED_LIMIT = 2.0  # k_v dt at which the held (sampled) velocity loop loses stability
# k_v / Theta above which the default active scheme is not run: measured, 12.5 (Table 4.1) and 5.6 (Table 4.2)
# track, 1875 (3.2.3's k4 = 3000) diverges at once; the limit in between is not mapped
OBSERVER_RATIO = 100.0


def default_k_v(case: Case) -> float:
    """The velocity gain the default tables use (see the module docstring)."""
    from .schemes import BUILT_IN

    if case.schemes.k_v is not None:
        return float(case.schemes.k_v)
    for s in BUILT_IN:
        cfg = getattr(case.schemes, s)
        if cfg is not None:
            return float(cfg.k_v)
    return KV_THESIS[case.kinematic.kind]


def _wanted(case: Case) -> list[str]:
    run = case.schemes.run
    return list(FAMILIES) if run is None else [s for s in FAMILIES if s in run]


def _physics_reason(case: Case, scheme: str, k_v: float) -> str | None:
    if scheme == "active_ukf":
        kdt = k_v * case.simulation.dt
        if kdt >= SAMPLED_LIMIT:
            return (
                f"the UKF holds its control over each {case.simulation.dt:g} s sample; with k_v = {k_v:g} the "
                f"sampled velocity loop has k_v dt = {kdt:.3g} >= 2 and is unstable"
            )
    if scheme == "active":
        theta = THETA_THESIS[case.kinematic.kind]
        if k_v / theta > OBSERVER_RATIO:
            return (
                f"the active law closes its k_v = {k_v:g} 1/s velocity loop on the Farza observer's estimate, whose "
                f"rate is Theta = {theta:g} 1/s: a ratio of {k_v / theta:.0f} (> {OBSERVER_RATIO:g}); measured on this "
                "case, the loop diverges within 10 ms"
            )
    return None


def not_applicable(case: Case) -> dict[str, str]:
    """Families of :data:`FAMILIES` the case does not run, each with a one-line reason."""
    out = {}
    for s in FAMILIES:
        if getattr(case.schemes, s) is not None:
            continue
        if case.schemes.run is not None and s not in case.schemes.run:
            out[s] = "left out by the case file (schemes.run)"
            continue
        why = _physics_reason(case, s, default_k_v(case))
        out[s] = why or "not configured"
    return out


def _patterns(case: Case, other: str):
    cfg = getattr(case.schemes, other)
    return "all" if cfg is None else cfg.patterns


def fill_defaults(case: Case, models: dict[str, type]) -> Case:
    """The case with a default table for every wanted family it does not configure.

    ``models``: the table model of each family (ftcreport.cases passes its own, so this module
    does not import the case schema: cases -> families, never back).
    """
    NominalScheme, OracleScheme, SwitchingScheme = models["nominal"], models["oracle"], models["switching"]
    AdaptiveScheme, ActiveScheme, ActiveUKFScheme = models["adaptive"], models["active"], models["active_ukf"]
    k_v = default_k_v(case)
    kind = case.kinematic.kind
    add = {}
    for s in _wanted(case):
        if getattr(case.schemes, s) is not None or _physics_reason(case, s, k_v) is not None:
            continue
        if s == "nominal":
            add[s] = NominalScheme(k_v=k_v)
        elif s == "oracle":
            add[s] = OracleScheme(k_v=k_v)
        elif s == "switching":
            add[s] = SwitchingScheme(k_v=k_v, gamma=10.0, T_min=0.01, patterns=_patterns(case, "adaptive"))
        elif s == "adaptive":
            add[s] = AdaptiveScheme(k_v=k_v, gamma=1.0, Gamma_f=1.0, patterns=_patterns(case, "switching"))
        elif s == "active":
            add[s] = ActiveScheme(k_v=k_v, Theta=THETA_THESIS[kind], k0=1.0, k1=1.0, p0=0.1)
        elif s == "active_ukf":
            nz = case.plant.noise
            std = max(nz.position, nz.heading)
            add[s] = ActiveUKFScheme(k_v=k_v, **({"meas_std": std} if std > 0 else {}))
    run = case.schemes.run or ()
    if "adaptive_frozen" in run and case.schemes.adaptive_frozen is None:
        pats = _patterns(case, "adaptive") if case.schemes.adaptive is not None else _patterns(case, "switching")
        add["adaptive_frozen"] = AdaptiveScheme(k_v=k_v, gamma=1.0, Gamma_f=1.0, patterns=pats)
    if not add:
        return case
    return case.model_copy(update={"schemes": case.schemes.model_copy(update=add)})
