r"""Every FTC family on every case: default scheme tables, and why a family cannot apply (pure).

A case runs :data:`FAMILIES` (the registered schemes that declare ``default_run``: nominal,
switching, adaptive, active with the Farza observer, active with the UKF, oracle) unless its file
narrows the list with ``schemes.run``.  A family whose table the file does not give gets the
scheme's default table (``Scheme.defaults``); a table the file gives is kept as written.  A
scheme that does not run by default (``adaptive_frozen``, an ablation of the adaptive law) gets
its default table only when ``schemes.run`` names it.

Defaults (thesis values; cases/README.md documents them; each scheme's file gives its own):

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

Cannot apply (:func:`not_applicable`, ``Scheme.not_applicable``): the UKF runs at the samples and
holds its control over each step of length dt, so the velocity error obeys e_(k+1) = (1 - k_v dt)
e_k: the sampled loop is unstable when k_v dt >= 2 (e.g. the thesis's k4 = 3000 at dt = 5 ms gives
15).  A default UKF table is not added then, and the reason is given instead of a run.  Likewise
the default active (Farza) table when k_v / Theta > 100: the law closes a k_v-fast velocity loop
on an observer of rate Theta (measured: k_v / Theta = 12.5 and 5.6 in Tables 4.1 and 4.2 track;
1875, the thesis's k4 = 3000 of 3.2.3, diverges within 10 ms).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from ..cases import Case

__all__ = ["FAMILIES", "KV_THESIS", "default_k_v", "fill_defaults", "not_applicable"]

KV_THESIS = {"two_link": 10.0, "chained": 2.0}


def _families() -> tuple[str, ...]:
    from ..schemes import built_in

    return tuple(name for name, sc in built_in().items() if sc.default_run)


FAMILIES = _families()  # the registry's schemes that run on every case by default


def default_k_v(case: Case) -> float:
    """The velocity gain the default tables use (see the module docstring)."""
    from ..schemes import built_in

    if case.schemes.k_v is not None:
        return float(case.schemes.k_v)
    for s in built_in():
        cfg = getattr(case.schemes, s)
        if cfg is not None:
            return float(cfg.k_v)
    return KV_THESIS[case.kinematic.kind]


def _wanted(case: Case) -> list[str]:
    run = case.schemes.run
    return list(_families()) if run is None else [s for s in _families() if s in run]


def _physics_reason(case: Case, scheme: str, k_v: float) -> str | None:
    from ..schemes import get

    hook = get(scheme).not_applicable
    return None if hook is None else hook(case, k_v)


def not_applicable(case: Case) -> dict[str, str]:
    """Families of :data:`FAMILIES` the case does not run, each with a one-line reason."""
    out = {}
    for s in _families():
        if getattr(case.schemes, s) is not None:
            continue
        if case.schemes.run is not None and s not in case.schemes.run:
            out[s] = "left out by the case file (schemes.run)"
            continue
        why = _physics_reason(case, s, default_k_v(case))
        out[s] = why or "not configured"
    return out


def fill_defaults(case: Case) -> Case:
    """The case with a default table (``Scheme.defaults``) for every wanted family it does not configure,
    and for every other built-in scheme ``schemes.run`` names without a table."""
    from ..schemes import built_in

    k_v = default_k_v(case)
    add = {}
    for s in _wanted(case):
        if getattr(case.schemes, s) is not None or _physics_reason(case, s, k_v) is not None:
            continue
        add[s] = built_in()[s].defaults(case, k_v)
    for s in case.schemes.run or ():
        sc = built_in().get(s)
        if sc is not None and not sc.default_run and getattr(case.schemes, s) is None and sc.defaults is not None:
            add[s] = sc.defaults(case, k_v)
    if not add:
        return case
    return case.model_copy(update={"schemes": case.schemes.model_copy(update=add)})
