"""``ftcreport analyze CASE --json`` (issue 37 item 8): the documented keys on every shipped case."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
from typer.testing import CliRunner

from ftcreport.analysis import analyze_case
from ftcreport.cases import configured_schemes, load_case
from ftcreport.cli import _public, app
from ftcreport.storage.store import _jsonable

ROOT = Path(__file__).resolve().parents[1]
CASES = sorted((ROOT / "cases").glob("*.toml")) + sorted((ROOT / "cases" / "motors").glob("*.toml"))

NUM = {"type": "number"}
NUM_OR_NULL = {"type": ["number", "null"]}
PAIR = {"type": "array", "items": NUM, "minItems": 2, "maxItems": 2}
LOOP = {
    "type": "object",
    "required": ["input"],
    "properties": {
        "input": {"type": "string"},
        "gain_margin": NUM_OR_NULL,
        "gain_margin_db": NUM_OR_NULL,
        "phase_margin_deg": NUM_OR_NULL,
        "stability_margin": NUM_OR_NULL,
        "disk_margin": NUM_OR_NULL,
        "open_loop_unstable": {"type": "integer"},
    },
}
MARGINS = {
    "anyOf": [
        {"type": "object", "required": ["note"], "properties": {"note": {"type": "string"}}},
        {
            "type": "object",
            "required": ["input", "unit", "loops"],
            "properties": {
                "input": {"enum": ["torque", "voltage", "current target"]},
                "loops": {"type": "array", "items": LOOP},
            },
        },
    ]
}
#: the keys README's table of a phase documents: on every phase, null where they are not computed
DOCUMENTED = ["t_worst", "pole_table", "internal_modes", "frozen_disagree", "states"]
STABILITY = ["stable", "marginal", "unstable", "inconclusive", "not computed"]
PHASE = {
    "type": "object",
    "required": [
        *["t_start", "t_end", "pattern_true", "pattern_applied", "discrete", "poles", "stable", "margins"],
        *DOCUMENTED,
    ],
    "properties": {
        "t_start": NUM,
        "t_end": NUM,
        "pattern_true": {"type": "array", "items": NUM},
        "pattern_applied": {"type": ["array", "null"], "items": NUM},
        "discrete": {"type": "boolean"},
        "poles": {"type": "array", "items": PAIR},
        "spectral_radius": NUM_OR_NULL,
        "max_real_part": NUM_OR_NULL,
        "stable": {"type": ["boolean", "null"]},
        "stability": {"enum": STABILITY},
        "margins": {"anyOf": [MARGINS, {"type": "null"}]},
    },
    "oneOf": [{"required": ["spectral_radius"]}, {"required": ["max_real_part"]}],
    # not computed: the reason in note, the documented keys null (README: the phase keys)
    "if": {"properties": {"stability": {"const": "not computed"}}},
    "then": {
        "required": ["note"],
        "properties": {
            "note": {"type": "string", "minLength": 1},
            **{k: {"type": "null"} for k in [*DOCUMENTED, "margins"]},
        },
    },
    "else": {"properties": {"margins": MARGINS}},
}
LIMITS = {
    "type": "object",
    "required": ["sample_time_max", "k_v_max"],
    "properties": {"sample_time_max": NUM_OR_NULL, "k_v_max": NUM_OR_NULL},
    "additionalProperties": False,
}
KINDS = {
    "type": "object",
    "propertyNames": {"pattern": "^(limits|velocity_loop)[.](sample_time_max|k_v_max)$"},
    "additionalProperties": {
        "enum": [
            "limit",
            "unbounded",
            "beyond_range",
            "unstable",
            "marginal",
            "not_computed",
            "not_searched",
            "not_applicable",
        ]
    },
}
SCHEMA = {
    "type": "object",
    "required": ["case", "limits", "phases", "closed_loop_poles", "controllability", "velocity_loop", "limit_kinds"],
    "properties": {
        "limit_kinds": {"type": "object", "additionalProperties": KINDS},
        "limits": {"type": "object", "additionalProperties": LIMITS},
        "velocity_loop": {"type": "object", "additionalProperties": LIMITS},
        "phases": {"type": "object", "additionalProperties": {"type": "array", "items": PHASE, "minItems": 1}},
        "closed_loop_poles": {"type": ["object", "null"], "additionalProperties": {"type": "array", "items": PAIR}},
        "controllability": {"type": "array", "items": {"type": "object", "required": ["pattern", "rank"]}},
        "observer": {"type": "object", "required": ["observability"]},
        "confirmation": {"type": "object"},
    },
}


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_analysis_keys_on_every_shipped_case(path):
    """Every scheme of every shipped case analysed, every phase with the keys of item 8 (README documents them)."""
    case = load_case(path)
    res = json.loads(json.dumps(_jsonable(_public(analyze_case(case)))))
    jsonschema.validate(res, SCHEMA)
    assert not res["not_analyzed"], res["not_analyzed"]
    assert set(res["phases"]) == set(res["limits"]) == set(configured_schemes(case))
    n_phases = len({0.0, *[float(f.time) for f in case.faults if 0 < f.time < case.simulation.duration]})
    assert all(len(p) == n_phases for p in res["phases"].values())
    if case.schemes.active is not None or case.schemes.active_ukf is not None:
        assert "observability" in res["observer"]
    assert "_curves" not in res
    assert all("_bode" not in (p["margins"] or {}) for ph in res["phases"].values() for p in ph)
    # every limit has its kind, "limit" exactly where it has a value (the summary and the page word a null by it)
    for scheme in res["limits"]:
        for where in ("limits", "velocity_loop"):
            for key, value in res[where][scheme].items():
                kind = res["limit_kinds"][scheme][f"{where}.{key}"]
                assert (kind == "limit") == (value is not None), (scheme, where, key, value, kind)
    # motor faults in words only on a motor case (README: the phase keys)
    assert all(("motor_faults" in p) == (case.actuators is not None) for ph in res["phases"].values() for p in ph)


def _readme_row(key: str) -> str:
    return next(ln for ln in (ROOT / "README.md").read_text().splitlines() if ln.startswith(f"| `{key}`"))


def _limits_table(env, rows: list[dict]) -> str:
    """templates/_analysis.html rendered with only the limits' rows (a sampled case at 5 ms, torque inputs)."""
    analysis = {
        "limit_rows": rows,
        "sampled": True,
        "sample_time": 0.005,
        "actuator_input": "torque",
        "not_analyzed": {},
    }
    return env.get_template("_analysis.html").render(analysis=analysis)


def test_readme_documents_the_keys_of_a_stopped_or_erred_confirmation_run():
    """A confirmation run that stopped early carries t_end and reason (analysis.confirm.classify), an erred
    one reason: the README's key table names them; motor_faults is said to be on motor cases only."""
    from types import SimpleNamespace

    from ftcreport.analysis.confirm import classify

    stopped = SimpleNamespace(status="diverged", t_end=1.25, reason="non-finite state at t = 1.25 s")
    run = classify(stopped, stopped, 0.005)
    assert {"t_end", "reason"} <= set(run)
    row = _readme_row("confirmation")
    runs = row[row.index('"runs"') : row.index('"agrees"')]
    for k in [*run, "reason"]:  # an erred run: {"outcome": "error", "reason"}
        assert f'"{k}"' in row, (k, runs)
    assert "only on motor cases" in _readme_row("pattern_true")


def test_cli_json_with_confirmation_on_a_motor_case():
    """The command prints one object; on a motor case each limit carries its two simulations."""
    path = ROOT / "cases" / "motors" / "two_link_switching_motors.toml"
    res = CliRunner().invoke(app, ["analyze", str(path), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    jsonschema.validate(data, SCHEMA)
    conf = data["confirmation"]["switching"]["sample_time_max"]
    assert [r["factor"] for r in conf["runs"]] == [0.9, 1.1]
    assert [r["outcome"] for r in conf["runs"]] == ["bounded", "limit cycle"] and conf["agrees"] is True
    assert conf["sentence"].startswith("predicted 1.37 ms; at 1.23 ms bounded, at 1.51 ms limit cycle")
    assert data["limits"]["switching"]["sample_time_max"] == pytest.approx(1.371e-3, rel=2e-3)


def _phase(t0, t1, stability, measure, discrete=True):
    key = "spectral_radius" if discrete else "max_real_part"
    return {"t_start": t0, "t_end": t1, "stability": stability, key: measure, "discrete": discrete}


def test_the_verdict_cites_the_analysis():
    """A scheme predicted unstable that completes 'chatters' (phase, spectral radius, the limit beyond the case's
    sample time); nominal among the winners with a stable loop in every phase is explained by it; the last FTC
    scheme with a stable loop 'loses on what it applies'.  Through compare.compare_case's hook."""
    from ftcreport import compare

    analysis = {
        "sample_time": 0.005,
        "k_v": {"switching": 3000.0, "nominal": 3000.0, "adaptive": 3000.0},
        "limits": {"switching": {"sample_time_max": 1.37e-3, "k_v_max": 559.0}},
        "phases": {
            "switching": [_phase(0, 20, "stable", 0.99), _phase(20, 50, "unstable", 10.7)],
            "nominal": [_phase(0, 20, "stable", 0.99), _phase(20, 50, "stable", 0.995)],
            "adaptive": [_phase(0, 20, "stable", 0.99), _phase(20, 50, "stable", 0.98)],
        },
    }
    runs = {
        s: {"status": "ok", "position_error_final": e, "phases": [{"position_error_max": e}, {"position_error_max": e}]}
        for s, e in (("nominal", 0.01), ("switching", 0.05), ("adaptive", 0.08))
    }
    v = compare.compare_case("c", runs, {"ok"}, [20.0], {"analysis": analysis, "limit": "the drive's voltage limit"})
    text = " ".join(v.sentences)
    assert "predicts switching's loop unstable in the phase 20-50 s (spectral radius 10.7" in text
    assert "its sample time 5 ms is beyond its limit 1.37 ms" in text and "chatter" in text
    assert "The analysis agrees: the healthy law's loop stays stable in every fault phase" in text
    assert "adaptive loses on what it applies, not on stability" in text
    # without the analysis, none of it
    assert "analysis" not in " ".join(compare.compare_case("c", runs, {"ok"}, [20.0], {}).sentences)


def test_a_loop_without_a_drive_limit_is_not_said_to_chatter_at_it():
    """two_link_adaptive_eight (ideal torques, continuous control, no motors) read "the wheels chatter at the
    drive's limit": a limit exists only with [actuators] or [plant] saturation.  The sentence says what holds
    for the case: ideal torques, or held by the saturation (continuous), or chatter at it (sampled)."""
    from ftcreport import compare
    from ftcreport.evaluation.verdict_analysis import limit_words, verdict_sentence

    analysis = {
        "k_v": {"adaptive": 3000.0, "nominal": 3000.0},
        "phases": {
            "adaptive": [_phase(0, 20, "stable", -0.1, False), _phase(20, 30, "unstable", 0.4672, False)],
            "nominal": [_phase(0, 20, "stable", -0.1, False), _phase(20, 30, "stable", -0.05, False)],
        },
    }
    runs = {
        s: {"status": "ok", "position_error_final": e, "phases": [{"position_error_max": e}, {"position_error_max": e}]}
        for s, e in (("nominal", 0.01), ("adaptive", 0.05))
    }
    ideal = load_case(ROOT / "cases" / "two_link_adaptive_eight.toml")
    assert limit_words(ideal) is None
    text = " ".join(compare.compare_case("c", runs, {"ok"}, [20.0], {"analysis": analysis}).sentences)
    assert "predicts adaptive's loop unstable in the phase 20-30 s (max Re 0.4672 1/s)" in text
    assert "drive's limit" not in text and "chatter" not in text
    # ideal torques: the predicted growth over the phase, against the run (session 12's new user: "the case
    # applies ideal torques" explained nothing); exp(0.4672 x 10) = 107, e-folding 1 / 0.4672 = 2.14 s
    assert "though the linearization grows by a factor 107 over the phase's 10 s (e-folding in 2.14 s)" in text
    assert "the linearization and the run disagree here" in text
    # a slow one (the UKF's spectral radius 1 + 4.8e-6 per 20 ms over 180 s: a factor 1.04, e-folding 4,167 s)
    slow = {"sample_time": 0.02, "k_v": {"adaptive": 3000.0},
            "phases": {"adaptive": [_phase(220, 400, "unstable", 1 + 4.8e-6)]}}  # fmt: skip
    line = verdict_sentence("adaptive", slow, "chatters")
    assert "its predicted growth is slow, a factor 1.04 over the phase's 180 s (e-folding in 4,167 s)" in line, line
    facts = {"analysis": analysis, "limit": "the saturation at 50 N m"}
    text = " ".join(compare.compare_case("c", runs, {"ok"}, [20.0], facts).sentences)
    assert "its run completed, the wheels' inputs held by the saturation at 50 N m." in text
    motors = load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml")
    assert limit_words(motors) == "the drive's voltage limit"


def test_schemes_the_analysis_says_the_same_of_share_one_sentence():
    """two_link_switching_motors: all three loops unstable in every phase with the same radius and limits read
    as one sentence ("in every fault phase", the largest radius), not three near-copies; a scheme with another
    radius keeps its own."""
    from ftcreport.analysis.summary import analysis_sentences

    names = ("switching", "oracle", "nominal", "other")
    analysis = {
        "sample_time": 0.005,
        "k_v": dict.fromkeys(names, 3000.0),
        "limits": {s: {"sample_time_max": 1.37e-3, "k_v_max": 559.0} for s in names},
        "phases": {s: [_phase(0, 20, "unstable", 10.66), _phase(20, 50, "unstable", 10.6)] for s in names[:3]},
    }
    analysis["phases"]["other"] = [_phase(0, 20, "stable", 0.9), _phase(20, 50, "unstable", 2.5)]
    out = analysis_sentences(analysis, list(names), ["switching"], [])
    assert out[0].startswith("The analysis predicts the loops of switching, oracle and nominal unstable in every "
                             "fault phase (spectral radius up to 10.66; the case's sample time 5 ms is "
                             "beyond their limit 1.37 ms")  # fmt: skip
    assert out[1].startswith("The analysis predicts other's loop unstable in the phase 20-50 s (spectral radius 2.5;")
    assert len(out) == 2
    # no sentence is split on which phase round-off made the largest (the motor page read two sentences, "worst
    # 80-110 s" and "worst 0-20 s", for radii equal to the digits shown)
    analysis["phases"] = {s: [_phase(0, 20, "unstable", 10.6601 + k * 1e-6), _phase(20, 50, "unstable", 10.6602)]
                          for k, s in enumerate(names)}  # fmt: skip
    out = analysis_sentences(analysis, list(names), ["switching"], [])
    assert len(out) == 1 and "worst" not in out[0], out
    assert out[0].startswith(
        "The analysis predicts the loops of switching, oracle, nominal and other unstable in every fault phase "
        "(spectral radius up to 10.66; the case's sample time 5 ms is beyond their limit 1.37 ms; k_v = 3000 1/s is "
        "beyond their largest stable 559 1/s)"
    ), out


def test_the_page_section_from_a_case_without_runs():
    """report.analysis_figs builds the section's rows and its four interactive figures, each with its SVG."""
    from ftcreport.report.analysis_figs import analysis_section

    case = load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml")
    sec = analysis_section(case, ["1r", "1l", "2r", "2l"], {}, [20.0, 50.0, 80.0, 110.0])
    ids = [f["id"] for f in sec["figures"]]
    assert ids[:3] == ["analysis-poles", "analysis-sweep-T", "analysis-sweep-k"]
    assert all(f["svg"].startswith("<svg") and f["plotly"]["data"] for f in sec["figures"][:3])
    row = sec["limit_rows"][0]
    assert row["T_factor"] == pytest.approx(1.371e-3 / 5e-3, rel=2e-3) and row["k_factor"] < 0.2
    assert [c["agrees"] for c in row["confirm"]] == [True, True]
    assert all(c["stability"] == "unstable" for r in sec["phase_rows"] for c in r["cells"])


def test_each_limit_note_names_its_limit():
    """A note is shown beside the scheme's limits: it says which limit it is about (three_link_switching_motors
    showed the velocity loop's 'stable at every sample time up to 10 s' under a 107 ms limit), one line for
    the limits a note is the same for, and empty notes left out."""
    from ftcreport.report.analysis_figs import _limit_notes

    notes = {
        "limits.sample_time_max": "",
        "limits.k_v_max": "the loop is unstable at the case's own gain",
        "velocity_loop.sample_time_max": "stable at every sample time up to 10 s",
        "velocity_loop.k_v_max": "the loop is unstable at the case's own gain",
    }
    assert _limit_notes(notes) == [
        "k_v max and velocity loop alone, k_v max: the loop is unstable at the case's own gain",
        "velocity loop alone, T_s max: stable at every sample time up to 10 s",
    ]


def _mixed_result():
    """An analysis result with a continuous-time scheme (nominal: s-plane poles, real-part sweep) beside a
    sampled one (active_ukf, whose filter runs at dt: z-plane poles, spectral-radius sweep)."""
    return {
        "sample_time": None,
        "k_v": {"nominal": 5.0, "active_ukf": 5.0},
        "limits": {"nominal": {"k_v_max": None}, "active_ukf": {"k_v_max": 199.0}},
        "phases": {
            "nominal": [
                {
                    "t_start": 0.0,
                    "t_end": 20.0,
                    "discrete": False,
                    "stability": "stable",
                    "poles": [[-1.9, 1.3], [-1.9, -1.3], [-10.0, 0.0]],
                }
            ],
            "active_ukf": [
                {
                    "t_start": 0.0,
                    "t_end": 20.0,
                    "discrete": True,
                    "stability": "stable",
                    "poles": [[0.98, 0.01], [0.98, -0.01], [0.5, 0.0]],
                }
            ],
        },
        "_curves": {
            "nominal": {"k": [1.0, 5.0, 50.0], "max_re_k": [-0.1, -0.5, -2.0]},
            "active_ukf": {"k": [1.0, 5.0, 50.0, 500.0], "rho_k": [0.99, 0.98, 0.9, 1.2]},
        },
    }


def test_a_continuous_schemes_poles_are_drawn_on_the_s_plane_beside_a_sampled_ones_z_plane():
    """The page audit (round 3): with the UKF (a discrete filter) among the runs the whole pole map became a
    z-plane, and nominal's continuous poles (-1.9 +- 1.3j, -10: stable) sat far outside the unit circle under
    'Re z'.  Each scheme's view has its own plane: the menu sets the axes and the boundary with the traces."""
    from ftcreport.report.analysis_figs import pole_map_fig

    fig = pole_map_fig(_mixed_result())
    layout = fig["plotly"]["layout"]
    buttons = {b["label"]: b for b in layout["updatemenus"][0]["buttons"]}
    views = {s: b["args"][1] for s, b in buttons.items()}
    assert views["nominal"]["xaxis.title.text"] == "Re s [1/s]"
    assert views["active_ukf"]["xaxis.title.text"] == "Re z"
    assert [s["type"] for s in views["nominal"]["shapes"]] == ["line"]  # the imaginary axis
    assert [s["type"] for s in views["active_ukf"]["shapes"]] == ["circle"]  # the unit circle
    # the first scheme's view is the one shown before any choice
    assert layout["xaxis"]["title"]["text"] == "Re s [1/s]" and layout["shapes"] == views["nominal"]["shapes"]
    assert "s-plane" in fig["caption"] and "z-plane" in fig["caption"]


def test_a_spectral_radius_and_a_largest_real_part_never_share_one_axis():
    """The page audit: the k_v sweep drew the UKF's spectral radius (about 1) on nominal's 'largest real part
    [1/s]' axis, above its stability boundary at 0, and its limit's diamond at 0, off its own curve.  Each
    measure has its own figure, boundary (0 or 1) and axis."""
    from ftcreport.report.analysis_figs import sweep_figs

    figs = sweep_figs(_mixed_result(), "k")
    assert len(figs) == 2
    by_axis = {f["plotly"]["layout"]["yaxis"]["title"]["text"]: f for f in figs}
    assert set(by_axis) == {"largest real part [1/s]", "spectral radius"}
    for title, f in by_axis.items():
        names = {t["name"] for t in f["plotly"]["data"] if t["mode"] == "lines"}
        assert names == ({"nominal"} if title.startswith("largest") else {"active_ukf"})
        edge = f["plotly"]["layout"]["shapes"][0]["y0"]
        assert edge == (0.0 if title.startswith("largest") else 1.0)
        for t in f["plotly"]["data"]:
            if t["mode"] == "markers" and t["marker"]["symbol"] == "diamond":
                assert t["y"] == [edge]  # a limit sits on its own measure's boundary
    assert len({f["id"] for f in figs}) == 2


def test_the_terminal_states_the_margins_as_the_page_does():
    """The page audit: 'analyze' printed the case's setting over the limit ('T_s 5 ms = 3.65x ... stable below
    1x') where the page gives the limit over the case's setting ('T_s max / case's 0.274', a factor above 1 is
    the margin): the same margins as reciprocals under opposite conventions.  Both now give limit / case."""
    from ftcreport.analysis.summary import text_summary

    res = {
        "case": "c",
        "n_robots": 2,
        "reference_kind": "circle",
        "sampled": True,
        "sample_time": 0.005,
        "k_v": {"switching": 3000.0},
        "limits": {"switching": {"sample_time_max": 1.37e-3, "k_v_max": 559.0}},
    }
    text = "\n".join(text_summary(res))
    assert "T_s max / T_s 5 ms = 0.274" in text and "k_v max / k_v 3000 1/s = 0.186" in text, text
    assert "a factor above 1 is room the case keeps" in text and "stable below 1x" not in text


def test_the_terminal_says_the_loop_is_unstable_and_names_margin_factors():
    """'analyze' printed "k_v_max: the case's own gain is unstable" (a loop is unstable, not a gain) and
    "margins: T_s max / T_s 5 ms = 0.274, ..." for the limit / case factors, beside the phases' gain and
    phase margins (GM, PM) a few lines below.  The note says the loop is unstable at the case's own gain,
    and the factors are "margin factors (limit / case value)"; the JSON keys are unchanged."""
    from ftcreport.analysis.limits import largest_gain
    from ftcreport.analysis.summary import text_summary

    lim = largest_gain(lambda k: k - 559.0, 3000.0)  # stable below 559 1/s: the case's 3000 1/s is beyond it
    assert lim["value"] == pytest.approx(559.0, rel=1e-3)
    assert lim["note"] == "the loop is unstable at the case's own gain"
    res = {
        "case": "c",
        "n_robots": 2,
        "reference_kind": "circle",
        "sampled": True,
        "sample_time": 0.005,
        "k_v": {"switching": 3000.0},
        "limits": {"switching": {"sample_time_max": 1.37e-3, "k_v_max": lim["value"]}},
        "limit_notes": {"switching": {"limits.k_v_max": lim["note"]}},
    }
    lines = text_summary(res)
    text = "\n".join(lines)
    assert "own gain is unstable" not in text and "margins:" not in text, text
    assert "      k_v_max: the loop is unstable at the case's own gain" in lines, text
    (factors,) = [ln for ln in lines if "T_s max / T_s 5 ms" in ln]
    assert factors.startswith("      margin factors (limit / case value): T_s max / T_s 5 ms = 0.274, "), factors
    assert "k_v max / k_v 3000 1/s = 0.186" in factors, factors


def test_a_limit_the_simulation_contradicts_shows_no_green_margin():
    """The page audit: three_link_switching_pi showed 'T_s max / case's 40' in green beside the confirmation
    in red 'at 180 ms limit cycle ... the simulation contradicts the prediction'.  A margin whose limit a
    simulation contradicts is marked as such, not as a margin the case keeps."""
    from jinja2 import Environment, FileSystemLoader

    from ftcreport.report.analysis_figs import limit_rows

    res = {
        "sample_time": 0.005,
        "k_v": {"switching": 5.0},
        "limits": {"switching": {"sample_time_max": 0.2, "k_v_max": 400.0}},
        "confirmation": {
            "switching": {
                "sample_time_max": {"agrees": False, "sentence": "predicted 200 ms; at 180 ms limit cycle"},
                "k_v_max": {"agrees": True, "sentence": "predicted 400 1/s; at 360 bounded, at 440 diverged"},
            }
        },
    }
    row = limit_rows(res)[0]
    assert row["T_contradicted"] is True and row["k_contradicted"] is False
    env = Environment(loader=FileSystemLoader(str(ROOT / "templates")))
    env.globals["fmt"] = lambda v: f"{v:.3g}"
    html = env.get_template("_analysis.html").render(
        analysis={
            "limit_rows": [row],
            "sampled": True,
            "sample_time": 0.005,
            "actuator_input": "torque",
            "not_analyzed": {},
        }
    )
    assert '<span class="fail">40 (contradicted)</span>' in html
    assert '<span class="ok">80</span>' in html
    # 'none' is "no finite limit" in the table's caption: a limit not searched (the UKF's) says so instead
    ukf = {
        "sample_time": 0.005,
        "k_v": {"active_ukf": 5.0},
        "limits": {"active_ukf": {"sample_time_max": None}},
        "limit_notes": {"active_ukf": {"limits.sample_time_max": "not searched: the UKF's gain comes from ..."}},
        "limit_kinds": {"active_ukf": {"limits.sample_time_max": "not_searched"}},
    }
    html = _limits_table(env, limit_rows(ukf))
    assert "<td>not searched</td>" in html
    # a null limit of a loop with no finite one reads so, not "none" (session 12's new user read "largest
    # stable k_v: none" as "no gain is stable")
    free = {"sample_time": 0.005, "k_v": {"nominal": 5.0}, "limits": {"nominal": {"sample_time_max": None,
            "k_v_max": None}}, "limit_notes": {}}  # fmt: skip
    html = _limits_table(env, limit_rows(free))
    row = html[html.index('data-scheme="nominal"') :].split("</tr>")[0]
    assert ">none<" not in row and row.count("no finite limit") >= 2, row
    from ftcreport.analysis.summary import fmt_limit

    assert fmt_limit(None, "s") == "no finite limit" and fmt_limit(None, "1/s") == "no finite limit"
    # a null says which null it is (the attack on analyze: "no finite limit" was printed for a loop unstable
    # at every point searched, or marginal, or not computed, whose JSON nulls only limit_notes told apart)
    assert fmt_limit(None, "s", "unbounded") == "no finite limit (stable up to 10 s)"
    assert fmt_limit(None, "1/s", "unbounded") == "no finite limit (stable up to 1e+06 1/s)"
    assert fmt_limit(None, "s", "unstable") == "no stable value (unstable throughout the search)"
    assert fmt_limit(None, "1/s", "marginal") == "no stable range (the loop is marginal)"
    assert fmt_limit(None, "s", "not_computed") == "not computed"
    assert fmt_limit(2.5e-3, "s", "limit") == "2.5 ms" and fmt_limit(250.0, "1/s", "limit") == "250 1/s"
    kinds = {"sample_time": 0.005, "k_v": {"nominal": 5.0}, "limits": {"nominal": {"sample_time_max": None,
             "k_v_max": None}}, "velocity_loop": {"nominal": {"sample_time_max": None, "k_v_max": None}},
             "limit_kinds": {"nominal": {"limits.sample_time_max": "unstable", "limits.k_v_max": "marginal",
                                         "velocity_loop.sample_time_max": "not_computed",
                                         "velocity_loop.k_v_max": "not_applicable"}}}  # fmt: skip
    html = _limits_table(env, limit_rows(kinds))
    row = html[html.index('data-scheme="nominal"') :].split("</tr>")[0]
    assert "<td>no stable value (unstable throughout the search)</td>" in row, row
    assert "<td>no stable range (the loop is marginal)</td>" in row and "not computed, n/a" in row, row


def test_a_phase_a_raising_plugin_law_leaves_not_computed_is_documented(tmp_path):
    """A plug-in law that raises at every frozen instant of a phase (not at the scheme check's t = 0 and
    1.3 s): its phases said stability "not computed", a value README did not document, and lacked the
    documented keys t_worst, pole_table, internal_modes, frozen_disagree and states."""
    import tomllib

    import tomli_w

    text = (ROOT / "examples" / "schemes" / "sliding_mode.py").read_text()
    line = "    out.u[:] = law_for_pattern(terms.MB, v, P.healthy)\n"
    assert line in text
    plugin = tmp_path / "raising.py"
    raising = '    if step.t > 2.0:\n        raise ValueError("plug-in law failed")\n'
    assert text.count('name="sliding_mode"') == 1
    # a name of its own: the example may be registered in this process already (one name, one law)
    plugin.write_text(text.replace(line, raising + line).replace('name="sliding_mode"', 'name="raising_law"'))
    data = tomllib.loads((ROOT / "cases" / "two_link_sliding_mode.toml").read_text())
    data["plugins"] = [str(plugin)]
    data["schemes"]["raising_law"] = data["schemes"].pop("sliding_mode")
    data["thresholds"].pop("sliding_mode", None)
    data["schemes"]["run"] = ["raising_law"]
    data["simulation"]["duration"] = 40.0
    path = tmp_path / "raising.toml"
    path.write_text(tomli_w.dumps(data))
    got = CliRunner().invoke(app, ["analyze", str(path), "--json"])
    assert got.exit_code == 0, got.output
    res = json.loads(got.stdout)
    jsonschema.validate(res, SCHEMA)
    phases = res["phases"]["raising_law"]
    assert phases and all(p["stability"] == "not computed" for p in phases), phases
    # the loop catches the law's exception (fast.loop._contract_law); the note names it as a run's reason does
    assert all("its law raised ValueError at t = " in p["note"] and "plug-in law failed" in p["note"] for p in phases)
    row = _readme_row("stable")  # README names the value and where its reason is
    assert all(f'"{v}"' in row for v in STABILITY), row
    assert "`note`" in row, row


def test_the_classic_keys_say_which_plant_they_are_of():
    """Session 12's new user: on the sampled motor case, `analyze --json` put the ideal continuous plant's
    closed_loop_poles, pole_tables and nominal_velocity_loop (stable, phase margin 90 deg) beside phases that
    are all unstable, with no word of which loop each describes.  ``classic_model`` says it, in the JSON, the
    text and the README's key table."""
    from ftcreport.analysis.case import classic_model
    from ftcreport.analysis.summary import text_summary

    motor = classic_model(load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml"))
    assert motor.startswith("the ideal plant in continuous time") and "motors" in motor and "sampling" in motor
    plain = classic_model(load_case(ROOT / "cases" / "two_link_switching.toml"))
    assert plain.startswith("the case's own loop")
    assert "classic_model" in _readme_row("classic_model")
    worst = [{"compensable_rule": True, "pattern": [1, 0], "gramian_min_eig": 1e-6}]
    res = {"case": "c", "n_robots": 2, "reference_kind": "unicycle", "classic_model": motor, "controllability": worst}
    lines = text_summary(res)
    assert any("ideal plant in continuous time" in ln for ln in lines), lines


def test_a_verdict_among_loops_all_predicted_unstable_says_so_first():
    """two_link_switching_motors (session 12's new user, M4): every loop chatters at the voltage limit, yet the
    verdict opened with a ranking of the chatter amplitudes and the analysis's sentence came after it.  When the
    analysis predicts every completed scheme's loop unstable in some phase, the ranking is among chattering
    loops: the analysis's sentence leads; when one loop is stable, the ranking leads as before."""
    from ftcreport import compare

    unstable = [_phase(0, 20, "unstable", 10.7), _phase(20, 50, "unstable", 10.7)]
    analysis = {
        "sample_time": 0.005,
        "k_v": {s: 3000.0 for s in ("nominal", "switching", "adaptive")},
        "limits": {s: {"sample_time_max": 1.37e-3, "k_v_max": 559.0} for s in ("nominal", "switching", "adaptive")},
        "phases": {s: unstable for s in ("nominal", "switching", "adaptive")},
    }
    runs = {
        s: {"status": "ok", "position_error_final": e, "phases": [{"position_error_max": e}, {"position_error_max": e}]}
        for s, e in (("nominal", 0.01), ("switching", 0.05), ("adaptive", 0.08))
    }
    facts = {"analysis": analysis, "limit": "the drive's voltage limit"}
    first = compare.compare_case("c", runs, {"ok"}, [20.0], facts).sentences
    assert first[0].startswith("The analysis predicts the loops of "), first
    assert "chatter" in first[0]
    assert any("nominal" in s and "analysis" not in s for s in first[1:])  # the ranking follows
    # one stable loop: the comparison's own sentences lead
    analysis["phases"] = dict(
        analysis["phases"], adaptive=[_phase(0, 20, "stable", 0.9), _phase(20, 50, "stable", 0.9)]
    )
    again = compare.compare_case("c", runs, {"ok"}, [20.0], facts).sentences
    assert "analysis" not in again[0], again


def test_the_summary_says_the_limits_are_the_healthy_loops_beside_unstable_fault_phases():
    """The limits are searched on the healthy pattern (README): beside a fault phase whose loop is unstable at
    the case's own setting, the summary says so on the scheme's lines, not only in the README (an unstable
    healthy phase, or an unstable phase of another scheme, is not named)."""
    from ftcreport.analysis.summary import text_summary

    def phase(t0, t1, sigma, stability, **extra):
        return {"t_start": t0, "t_end": t1, "pattern_true": sigma, "friction_true": [0.0] * 4, "stability": stability,
                "max_re": -1.0, "discrete": False} | extra  # fmt: skip

    healthy = [1.0, 1.0, 1.0, 1.0]
    res = {
        "case": "probe", "n_robots": 2, "reference_kind": "circle",
        "limits": {s: {"sample_time_max": None, "k_v_max": 50.0} for s in ("nominal", "oracle")},
        "limit_kinds": {s: {"limits.sample_time_max": "unbounded", "limits.k_v_max": "limit"} for s in ("nominal",
                                                                                                      "oracle")},
        "phases": {
            "nominal": [phase(0, 30, healthy, "stable"), phase(30, 60, [1.0, 0.0, 1.0, 1.0], "unstable"),
                        phase(60, 70, healthy, "unstable", motor_faults=["1r: open"])],
            "oracle": [phase(0, 30, healthy, "unstable"), phase(30, 60, [1.0, 0.0, 1.0, 1.0], "stable")],
        },
    }  # fmt: skip
    lines = text_summary(res)
    said = [line for line in lines if "the limits are the healthy loop's" in line]
    assert said == ["      the limits are the healthy loop's: its faulty phase(s) 30-60 s, 60-70 s are unstable at the "
                    "case's own setting"], lines  # fmt: skip
    assert any(line.startswith("  nominal (healthy pattern): largest stable sample time") for line in lines)
    from ftcreport.report.analysis_figs import limit_rows  # the page's limits table: the same words, its note row

    notes = {r["scheme"]: r["notes"] for r in limit_rows(res)}
    assert notes["nominal"] == [said[0].strip()] and notes["oracle"] == []
