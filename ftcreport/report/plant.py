r"""The case page's "Plant and its idealizations" block (templates/_plant.html, issue 36 items 2, 3, 6).

:func:`plant_block` builds the block's dict from the validated case and the stored runs:

* what the simulated plant includes and what it leaves out, row by row (the chain, the wheels on
  the ground, the actuators, the faults, the sensors, the control's timing, the integration, what
  the controllers' model holds), so that a reader knows what a number does and does not include;
* with ``[actuators]``: the motors as the plant has them beside what the drive assumes (its model of
  the motor, the drag it compensates, its current loop), differences marked;
* with ``[actuators]`` and a switching run: the bank's identification, the exact-match fraction
  against the base case's without motors, the causes that keep it apart (each with its measured
  number), and a figure of the applied model against the true pattern with the cost ratios.

Pure: dicts in, dicts out (the figure is a plotly spec as ftcreport.report.interactive's).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..cases import Case, configured_schemes
from ..control.switching import TIE_RTOL
from ..model.actuators import DRIVE_MODEL_FIELDS
from ..model.faults import wheel_names
from ..runs import AUTO_METHODS
from ..storage.store import stored_metrics
from .interactive import _layout, _r, _trace, decimate

__all__ = ["identification_fig", "plant_block"]

#: (symbol, unit, description) of the motor rows of the table; the drive's model has the first seven.
_MOTOR_ROWS = (
    ("R_a", "ohm", "armature resistance"),
    ("L_a", "H", "armature inductance"),
    ("k_m", "N m/A", "torque constant"),
    ("k_b", "V s/rad", "back-EMF constant"),
    ("N", "1", "gear ratio"),
    ("eta_g", "1", "gear efficiency"),
    ("b_m", "N m s/rad", "rotor viscous drag (drive: the part it compensates)"),
    ("J_m", "kg m^2", "rotor inertia"),
    ("V_max", "V", "supply (the drive's output limit)"),
    ("I_max", "A", "current-target limit"),
)

#: Gap in exact identification [fraction] beyond which the block says why the motor case differs from its base.
IDENTIFICATION_GAP = 0.05


def _g(x: float) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "none"
    return f"{x:.4g}"


def _per_robot(values: list[float]) -> str:
    """One value, or the robots' values leader first when they differ."""
    return _g(values[0]) if all(v == values[0] for v in values) else ", ".join(_g(v) for v in values)


def _motor_rows(case: Case) -> tuple[list[dict], dict]:
    """The motor table's rows (plant against the drive's model) and the drive's settings."""
    motors = case.motor_params()
    drives = case.drive_params()
    rows = []
    for key, unit, what in _MOTOR_ROWS:
        plant = [getattr(m, key) for m in motors]
        if key in DRIVE_MODEL_FIELDS:
            drive = [d.b_m_compensated if key == "b_m" else getattr(d, key) for d in drives]
            differs = any(a != b for a, b in zip(plant, drive, strict=True))
            drive_txt = _per_robot(drive)
        else:
            differs = False
            drive_txt = "(the plant's)" if key in ("V_max", "I_max") else "not modelled"
        rows.append({"key": key, "unit": unit, "what": what, "plant": _per_robot(plant), "drive": drive_txt,
                     "differs": differs})  # fmt: skip
    d = drives[0]
    if d.driver == "static":
        kind = (
            "static inversion: v = R_a i* + k_b N omega (no current feedback; under sampled control the voltage "
            "of the sample is held)"
        )
        loop = None
    else:
        kind = (
            "PI current loop, conditional-integration anti-windup at the supply"
            + (f", sampled at {d.drive_rate:g} Hz (voltage held)" if d.drive_rate else ", continuous")
            + (", back-EMF feedforward" if d.back_emf_feedforward else ", no back-EMF feedforward")
        )
        loop = {
            "bandwidth": _per_robot([x.current_bandwidth for x in drives]),
            "tau_ms": _per_robot([1e3 / (2.0 * math.pi * x.current_bandwidth) for x in drives]),
            "kp": _per_robot([x.kp for x in drives]),
            "ki": _per_robot([x.ki for x in drives]),
            "gains": "given" if d.current_kp is not None or d.current_ki is not None else "pole-zero cancellation",
        }
    comp = ", ".join(dict.fromkeys(f"{100 * x.b_m_compensation:.4g} %" for x in drives))
    return rows, {"kind": kind, "loop": loop, "compensation": comp}


def _filter_clock(case: Case) -> str:
    """The discrete-time filters' clock (the UKF's: a scheme whose update starts at t0): once a measurement under
    continuous control (fast.engine.disc_ticks), at each sample under sampled control; "" when the case runs none."""
    from ..schemes.registry import discrete_time

    names = [s for s in configured_schemes(case) if discrete_time(s)]
    if not names:
        return ""
    sim = case.simulation
    if sim.sample_time is not None:  # sampled control: the filter's update is part of the sample (fast.loop.sample)
        return f"; {', '.join(names)}: a discrete-time filter, updated at each sample"
    period = case.plant.noise.period(sim.dt)
    return f"; {', '.join(names)}: a discrete-time filter, updated once a measurement (every {period:g} s)"


def _idealizations(case: Case) -> list[dict]:
    """What the plant includes and leaves out, one row per aspect."""
    r, sim, pl = case.robots, case.simulation, case.plant
    motors = case.actuators is not None
    mm = pl.mismatch
    factors = {k: getattr(mm, k) for k in ("a", "b", "r", "m", "I", "d")}
    mismatched = [k for k, v in factors.items() if v != 1.0]
    differ = (
        f"; the plant's {', '.join(mismatched)} differ from the controllers' ([plant.mismatch])" if mismatched else ""
    )
    rows = [
        {
            "aspect": "chain",
            "includes": f"{r.n} rigid robots (mass, yaw inertia, axle, wheels of [robots]) joined by rigid links "
            "at the axle midpoints, the Lagrangian model (2.70)" + differ,
            "leaves_out": "link compliance and play, the hitches' mass and friction",
        },
        {
            "aspect": "wheels on the ground",
            "includes": "rolling without slip or sideways sliding: the nonholonomic constraints hold exactly",
            "leaves_out": "slip, tyre deformation, rolling resistance (except a fault's ubar), uneven ground",
        },
    ]
    if case.actuators is None:
        sat = f", saturated at +-{pl.saturation:g} N m" if pl.saturation is not None else ""
        rows.append(
            {
                "aspect": "actuators",
                "includes": "ideal torque sources: the wheel torque is the command, tau = sigma sat(u) + ubar "
                f"(2.102){sat}",
                "leaves_out": "motors, drives and gears: no lag, no supply or current limit, no rotor inertia",
            }
        )
    else:
        d = case.drive_params()[0]
        rows.append(
            {
                "aspect": "actuators",
                "includes": "a DC motor per wheel behind a gear (2.26)-(2.29), ERRATA E19: armature current and "
                "back-EMF, rotor inertia eta_g N^2 J_m on the wheel axis, viscous drag, gear efficiency, the supply "
                f"limit; driven by a {'static' if d.driver == 'static' else 'PI current-loop'} drive (table below)",
                "leaves_out": "brushes and commutation, PWM ripple (the drive's average voltage), temperature drift of "
                "R_a and k_m, gear backlash and stiction, current-sensor noise",
            }
        )
        equal = all(
            getattr(dp, k) == getattr(mp, k)
            for dp, mp in zip(case.drive_params(), case.motor_params(), strict=True)
            for k in DRIVE_MODEL_FIELDS
        ) and all(dp.b_m_compensation == 1.0 for dp in case.drive_params())  # fmt: skip
        rows.append(
            {
                "aspect": "what the drive knows",
                "includes": "its own model of the motor ([actuators.drive_model]): "
                + ("the plant's exactly, all drag compensated" if equal else "differs from the plant's (table below)"),
                "leaves_out": "no fault: it drives a faulted motor as a healthy one",
            }
        )
    rows.append(
        {
            "aspect": "faults",
            "includes": "per wheel, effectiveness and friction from the event time on, tau = sigma u + ubar (2.101)"
            + ("; motor faults (k_m loss, resistance, open, short, stuck driver) in the motor model" * motors),
            "leaves_out": "gradual degradation between events, sensor faults",
        }
    )
    nz = pl.noise
    noisy = nz.noisy
    rows.append(
        {
            "aspect": "sensors",
            "includes": (
                f"q and eta with white noise (std {nz.position:g} m, {nz.heading:g} rad, {nz.velocity:g} m/s), "
                f"one draw every {nz.period(sim.dt):g} s, held in between"
                if noisy
                else "the controllers read q and eta exactly"
            )
            + (f", {sim.measurement_delay} sample(s) late" if sim.measurement_delay else ""),
            "leaves_out": "quantization, encoder resolution" + ("" if noisy else ", noise"),
        }
    )
    rows.append(
        {
            "aspect": "control timing",
            "includes": (
                f"sampled at T_s = {sim.sample_time:g} s, the command held between samples (zero-order hold)"
                if sim.sample_time is not None
                else "continuous-time control (the law evaluated at every stage of the integration)"
            )
            + _filter_clock(case),
            "leaves_out": "computation time, jitter",
        }
    )
    rows.append(
        {
            "aspect": "integration",
            "includes": f"{sim.method} at dt = {sim.dt:g} s: every number carries the integrator's error "
            "('ftcreport run --verify-dt' compares dt/2)"
            if sim.method not in AUTO_METHODS
            else f"{sim.method}, error-controlled at rtol = {sim.rtol:g}, atol = {sim.atol:g}, longest step "
            f"{sim.dt:g} s (the method each run took: Provenance): every number carries a local error within "
            "that tolerance per step ('ftcreport run --verify-dt' re-runs at rtol/10, atol/10 and dt/2)",
            "leaves_out": "-",
        }
    )
    sw = case.schemes.switching
    knows = "the chain of [robots] alone, as in the thesis"
    if case.actuators is not None:
        knows += "; the motors are not in the laws' model"
        if sw is not None and sw.rotor_inertia and "switching" in configured_schemes(case):
            knows += " (the switching bank's filters add the rotors' inertia: rotor_inertia)"
    rows.append({"aspect": "the controllers' model", "includes": knows, "leaves_out": "-"})
    return rows


def _reasons(case: Case, metrics: dict, base_exact: float | None) -> list[str]:
    """Why a motor case's switching identification stays below its base's, from what the case holds."""
    out = []
    sim = case.simulation
    sw = case.schemes.switching
    d = case.drive_params()[0]
    if metrics.get("status") not in (None, "ok"):
        why = metrics.get("reason") or "-"
        out.append(f"the run stopped ({metrics['status']}: {why}), so the fraction covers only part of it")
    if sim.sample_time is not None:
        kT = sw.k_v * sim.sample_time
        if kT >= 2.0:
            out.append(
                f"the sampled velocity loop is unstable, k_v T_s = {kT:.3g} > 2: the wheels chatter at the supply "
                "limit and the bank sees a limit cycle, not the faults"
            )
        if d.driver == "static":
            out.append(
                "the static drive holds its voltage over each sample, so the back-EMF of the changing wheel speeds "
                "moves the torque away from the command, an error the bank reads as lost torque; measured on "
                "three_link_switching_motors: 62 % exact with the thesis's cost, 97.8 % with c_int = 10, "
                "forgetting = 1 (99.6 % without motors); a PI current drive removes it (three_link_switching_pi)"
            )
    if sw.c_int == 0.0:
        out.append(
            "the thesis's instantaneous cost (c_int = 0): a model chosen on one moment of mismatch stays, because "
            "the wheels it leaves undriven cannot be tested (their costs tie); a forgetting integral (c_int > 0) "
            "averages such moments out"
        )
    if not sw.rotor_inertia:
        out.append(
            "the bank's filters leave out the rotors' inertia (rotor_inertia = false): it reads the missing inertia "
            "as lost torque (measured 58 % exact on three_link_switching_motors in continuous time)"
        )
    partial = [f for f in case.faults if f.motor is None and (0.0 < f.sigma < 1.0 or f.ubar != 0.0)]
    if partial:
        out.append(
            f"{len(partial)} fault event(s) with a partial effectiveness or a friction: the bank's 0/1 patterns "
            "cannot match them exactly, with or without motors"
        )
    if not out and base_exact is not None:
        out.append("none of the known causes applies: the difference is unexplained")
    return out


def identification_fig(ts: dict, patterns: list[list[int]], events: list[float]) -> dict | None:
    """Applied model against the true pattern, and the cost ratios that decide it (issue 36 item 3).

    Top: the model index applied and the true pattern's index (-1: not in the bank).  Bottom, log
    scale: (J_k - min J) / min J of the true pattern's model, the healthy model and the applied one;
    0 (an exact tie) is drawn at 1e-12; below the tie tolerance 1e-9 the rule treats costs as equal.
    """
    if "cost" not in ts or "selected" not in ts or "sigma" not in ts:
        return None
    J = np.asarray(ts["cost"], float)
    pats = [tuple(int(v) for v in p) for p in patterns]
    truth = np.array([pats.index(k) if (k := tuple((s >= 1.0).astype(int))) in pats else -1 for s in ts["sigma"]])
    sel = np.round(np.asarray(ts["selected"], float)).astype(int)
    jmin = J.min(axis=1)
    scale = np.where(jmin > 0, jmin, np.nan)
    rows = np.arange(J.shape[0])

    def excess(idx):
        ok = idx >= 0
        v = np.full(J.shape[0], np.nan)
        v[ok] = (J[rows[ok], idx[ok]] - jmin[ok]) / scale[ok]
        return np.where(np.isfinite(v), np.maximum(v, 1e-12), np.nan)

    ex_true, ex_healthy, ex_applied = excess(truth), excess(np.zeros_like(sel)), excess(sel)
    t, sel_d, tr_d, a, b, c = decimate(ts["t"], sel.astype(float), truth.astype(float), ex_true, ex_healthy, ex_applied)
    t_end = float(ts["t"][-1])
    data = [
        _trace(t, tr_d.astype(int).tolist(), "true pattern", "true %{y}",
               line={"shape": "hv", "color": "rgba(0,0,0,0.35)", "width": 4}),
        _trace(t, sel_d.astype(int).tolist(), "applied model", "model %{y}",
               line={"shape": "hv", "color": "#d62728", "width": 1.2}),
        _trace(t, _r(a), "cost excess of the true model", "%{y:.3g}", yaxis="y2", line={"color": "#222", "width": 1.2}),
        _trace(t, _r(b), "cost excess of the healthy model", "%{y:.3g}", yaxis="y2",
               line={"color": "#1f77b4", "width": 1, "dash": "dot"}),
        _trace(t, _r(c), "cost excess of the applied model", "%{y:.3g}", yaxis="y2",
               line={"color": "#d62728", "width": 1, "dash": "dash"}),
    ]  # fmt: skip
    lay = _layout(
        "switching with motors: applied model against the true pattern (top); (J_k - min J) / min J (bottom)",
        [{"start": e, "end": e, "color": None, "label": ""} for e in events],  # a dotted line at each fault event
        t_end,
        height=480,
        yaxis={"title": {"text": "model index"}, "domain": [0.58, 1.0]},
        yaxis2={"title": {"text": "cost excess"}, "type": "log", "domain": [0.0, 0.48], "exponentformat": "power"},
    )
    lay["xaxis"]["anchor"] = "y2"  # the time axis under the bottom panel
    lay["shapes"] = [dict(s, yref="paper") for s in lay["shapes"]] + [
        {"type": "line", "xref": "x", "yref": "y2", "x0": 0, "x1": t_end, "y0": TIE_RTOL, "y1": TIE_RTOL,
         "line": {"color": "rgba(0,0,0,0.4)", "width": 1, "dash": "dash"}},
    ]  # fmt: skip
    return {"data": data, "layout": lay}


def plant_block(case: Case, runs: list[dict], series: dict, out: Path | None = None, base: str | None = None) -> dict:
    """The dict templates/_plant.html renders (module docstring).

    ``runs``: the stored metrics of every scheme (``scheme``, ``status``, switching fractions,
    ``patterns``); ``series``: their stored time series; ``out``/``base``: the report directory and
    the base case's name, to compare identification with the base's run when it is in the report.
    """
    block: dict = {"rows": _idealizations(case), "motors": None, "identification": None}
    if case.actuators is None:
        return block
    rows, drive = _motor_rows(case)
    block["motors"] = {"rows": rows, "drive": drive, "wheels": ", ".join(wheel_names(case.robots.n))}
    sw = next((m for m in runs if m.get("scheme") == "switching"), None)
    if sw is None or sw.get("switching_exact_match_fraction") is None:
        return block
    base_exact = None
    if out is not None and base:
        bm = stored_metrics(Path(out), base).get("switching") if (Path(out) / base).is_dir() else None
        base_exact = None if bm is None else bm.get("switching_exact_match_fraction")
    exact = sw["switching_exact_match_fraction"]
    gap = None if base_exact is None else base_exact - exact
    ts = series.get("switching")
    fig = None
    if ts is not None and sw.get("patterns"):
        fig = identification_fig(ts, sw["patterns"], [float(t) for t in case.fault_schedule().times])
    s = case.schemes.switching
    block["identification"] = {
        "exact": exact,
        "effective": sw.get("switching_match_fraction"),
        "base": base,
        "base_exact": base_exact,
        "gap": gap,
        "within": gap is not None and gap <= IDENTIFICATION_GAP,
        "reasons": _reasons(case, sw, base_exact) if gap is None or gap > IDENTIFICATION_GAP else [],
        "cost": f"c_inst = {s.c_inst:g}, c_int = {s.c_int:g}, forgetting = {s.forgetting:g} 1/s",
        "rotors": bool(s.rotor_inertia),
        "figure": fig,
    }
    return block
