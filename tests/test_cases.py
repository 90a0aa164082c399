"""Case files: every file in cases/ validates; malformed cases give one clear error."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from ftcreport.cases import load_case, parse_case
from ftcreport.errors import CaseError
from ftcreport.runner import build

CASES = Path(__file__).resolve().parents[1] / "cases"
ALL = sorted(CASES.glob("*.toml"))
MOTORS = sorted(CASES.glob("motors/*.toml"))  # the DC-motor overlays (issue 19)


@pytest.mark.parametrize("path", ALL + MOTORS, ids=[p.stem for p in ALL + MOTORS])
def test_every_case_validates_and_builds(path):
    case = load_case(path)
    assert case.name == path.stem
    built = build(case)
    built.reference.check(case.simulation.duration, dt=0.5)
    assert built.q0.shape == (case.robots.n + 2,)


def _base() -> dict:
    return tomllib.loads((CASES / "three_link_switching.toml").read_text())


@pytest.mark.parametrize(
    ("mutate", "where", "why"),
    [
        (lambda c: c["faults"][2].update(wheel="4r"), "faults[2].wheel", "'4r' is not a wheel of a 3-robot chain"),
        (lambda c: c["robots"].update(m=-3.0), "robots.m", "must be > 0, got -3.0"),
        (lambda c: c["robots"].update(r=[0.15, 0.0, 0.15]), "robots.r[1]", "must be > 0"),
        (lambda c: c["robots"].update(colour="red"), "robots.colour", "unknown field"),
        (lambda c: c["faults"].reverse(), "faults", "sorted by time"),
        (lambda c: c["simulation"].update(dt="fast"), "simulation.dt", "a number is expected, got the text 'fast'"),
        (lambda c: c["faults"][0].update(sigma=1.5), "faults[0].sigma", "must be <= 1, got 1.5"),
        (lambda c: c["robots"].update(d=[1.0]), "robots.d", "1 link lengths given, a 3-robot chain needs 2"),
        (lambda c: c["faults"][-1].update(time=500.0), "faults[9].time", "before the end"),
        (lambda c: c["kinematic"].update(kind="two_link"), "kinematic.kind", "needs 2 robots"),
        (
            lambda c: c["schemes"]["switching"].update(patterns=[["1r", "1l"]]),
            "schemes.switching.patterns[0]",
            "uncompensable",
        ),
        (lambda c: c["schemes"].update(run=[]), "schemes", "no scheme"),
        (lambda c: c["schemes"].update(run=["nominal"]), "schemes.switching", "not listed in schemes.run"),
        (lambda c: c["schemes"].update(run=["nominal", "magic"]), "schemes.run[1]", "unknown scheme 'magic'"),
        (lambda c: c.pop("reference"), "reference", "required and missing: the last robot's path ([reference])"),
        (
            lambda c: c["simulation"].pop("duration"),
            "simulation.duration",
            "required and missing: simulated time; add it to [simulation]",
        ),
        (lambda c: c.update(expected_status_of={"adaptiv": ["ok"]}), "expected_status_of.adaptiv", "'adaptive'"),
        # session 9 fuzzing (tests/test_fuzz.py): a boolean or a quoted number was read as a number
        (lambda c: c["faults"][0].update(sigma=True), "faults[0].sigma", "a number is expected, got the boolean true"),
        (lambda c: c["robots"].update(n=True), "robots.n", "a number is expected, got the boolean true"),
        (lambda c: c["robots"].update(d="1.0"), "robots.d", "got the text '1.0' (write it without quotes)"),
        (lambda c: c["simulation"].update(log_every="5"), "simulation.log_every", "a number is expected, got the text"),
        (lambda c: c.update(actuators={"R_a": [0.3, True, 0.3]}), "actuators.R_a[1]", "got the boolean true"),
        # ... pydantic's words for a wrong type ("Input should be a valid dictionary or instance of Simulation")
        (lambda c: c.update(simulation=3), "simulation", "a table is expected, got the number 3"),
        (lambda c: c.update(description=3), "description", "a text (in quotes) is expected, got the number 3"),
        (lambda c: c["robots"].update(d={}), "robots.d", "a number is expected, got a table"),
        (lambda c: c["simulation"].update(log_every=1.5), "simulation.log_every", "a whole number is expected"),
        (lambda c: c["reference"].update(ccw="yes"), "reference.ccw", "true or false is expected, got the text 'yes'"),
        (lambda c: c["initial"].update(eta=[1.0, 2.0, 3.0]), "initial.eta", "at most 2 values are expected, got 3"),
        (lambda c: c["initial"].update(eta=[1.0]), "initial.eta[1]", "item 1 is missing: initial.eta needs 2 values"),
        (lambda c: c["simulation"].update(dt=float("nan")), "simulation.dt", "must be a finite number, got nan"),
        # ... a unicycle turning so slowly its circle's centre lies 1e210 m away (the run "diverged" to 1e194 m)
        (
            lambda c: c.update(reference={"kind": "unicycle", "v_d": 0.5, "omega_d": -4.6e-211}),
            "reference.omega_d",
            "radius v_d / |omega_d| = 1.09e+210 m, beyond 100000 m",
        ),
        # ... an empty list of expected outcomes: a run ending 'ok' failed with "active: ok: -"
        (lambda c: c.update(expected_status=[]), "expected_status", "empty: every run would count as failed"),
        (
            lambda c: c.update(expected_status_of={"switching": []}),
            "expected_status_of.switching",
            "empty: every run of switching would count as failed, even 'ok'; list some of 'ok', 'singular'",
        ),
        # ... a model bank without a model (the run failed with exit 1), or with one model twice
        (lambda c: c["schemes"]["switching"].update(patterns=[]), "schemes.switching.patterns", "no pattern"),
        (
            lambda c: c["schemes"]["switching"].update(patterns=[[], ["2l", "1r"], ["1R", "2l"]]),
            "schemes.switching.patterns[2]",
            "['1R', '2l'] is the model of patterns[1] again",
        ),
        (
            lambda c: c["schemes"]["switching"].update(patterns=[["2l", "2l"]]),
            "schemes.switching.patterns[0]",
            "wheel '2l' is listed twice",
        ),
        # ... absolute headings at the articulation singularity: validated, then the run stopped at t = 0
        (
            lambda c: c["initial"].update(mode="absolute", headings_deg=[0.0, 30.0, 118.5]),
            "initial.headings_deg",
            "theta_2 - theta_3 = -88.5 deg starts within simulation.singularity_margin_deg = 2 deg of +/-90 deg",
        ),
        # round-3 gate attack: a bound no value can satisfy was accepted
        (
            lambda c: c["thresholds"]["switching"].update(position_error_final={"min": 2.0, "max": 1.0}),
            "thresholds.switching.position_error_final",
            "min = 2 is above max = 1: no value can satisfy both",
        ),
        # round-3 case audit: a field of another reference or kinematic kind was silently ignored
        (lambda c: c["reference"].update(radius=2.0), "reference.radius", "not used by a 'sinusoid' reference"),
        (
            lambda c: c["reference"].update(kind="eight"),
            "reference.speed",
            "not used by an 'eight' reference (used by: circle, line, sinusoid)",
        ),
        (lambda c: c["kinematic"].update(k1=10.0), "kinematic.k1", "not used by a 'chained' kinematic law"),
        # session 13's attack: a loss and its repair 1e-13 s apart made a phase shorter than the requirements'
        # edge slack (1 ns): a window ran past the next event, two windows judged the same steps
        (
            lambda c: c["faults"][1].update(time=20.0 + 1e-13),
            "faults[1].time",
            "s after event 0 (t = 20.0 s): distinct event times must be at least 1e-09 s apart",
        ),
        # ... a sampling period or a measurement delay longer than the run was accepted
        (
            lambda c: c["simulation"].update(duration=5.0, sample_time=6.0),
            "simulation.sample_time",
            "6.0 s is longer than the run (5.0 s): the controller would act once",
        ),
        (
            lambda c: c["simulation"].update(duration=5.0, sample_time=0.02, measurement_delay=250),
            "simulation.measurement_delay",
            "250 sample(s) of 0.02 s (5 s) is not shorter than the run (5.0 s)",
        ),
    ],
)
def test_malformed_cases_name_file_field_and_reason(mutate, where, why):
    data = _base()
    mutate(data)
    with pytest.raises(CaseError) as info:
        parse_case(data, "cases/x.toml")
    msg = str(info.value)
    assert msg.startswith(f"cases/x.toml: {where}: "), msg
    assert why in msg, msg
    assert "\n" not in msg


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(CaseError, match="cannot read"):
        load_case(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[robots\nn = 2")
    with pytest.raises(CaseError, match=r"bad\.toml: not valid TOML"):
        load_case(bad)


# ------------------------------------------------------------------ every family by default (issue 21)
def test_every_shipped_case_runs_every_family_or_says_why():
    from ftcreport.evaluation.families import FAMILIES, not_applicable

    for path in ALL:
        case = load_case(path)
        missing = not_applicable(case)
        for s in FAMILIES:
            assert (getattr(case.schemes, s) is not None) != (s in missing), (path.stem, s)
        # a family is left out only for a stated physical reason, never silently
        for s, why in missing.items():
            assert "k_v" in why and ("unstable" in why or "diverges" in why), (path.stem, s, why)
    assert set(not_applicable(load_case(CASES / "two_link_switching.toml"))) == {"active", "active_ukf"}


def test_default_tables_follow_the_case_and_the_thesis():
    data = _base()  # three links (chained form), nominal/switching/oracle with k_v = 2 and five models
    case = parse_case(data, "x.toml")
    assert case.schemes.adaptive.k_v == 2.0 and case.schemes.adaptive.gamma == 1.0
    assert case.schemes.adaptive.patterns == case.schemes.switching.patterns  # the same model bank
    assert case.schemes.active.Theta == 0.9 and case.schemes.active.k_v == 2.0  # Table 4.2 (chained form)
    assert case.schemes.active_ukf.k_v == 2.0
    two = tomllib.loads((CASES / "two_link_intermittent.toml").read_text())
    two["schemes"] = {"k_v": 7.0}
    c2 = parse_case(two, "y.toml")
    assert c2.schemes.nominal.k_v == c2.schemes.oracle.k_v == 7.0
    assert c2.schemes.active.Theta == 1.6  # Table 4.1 (two links)
    assert c2.schemes.switching.patterns == "all" and c2.schemes.switching.gamma == 10.0
    two["schemes"] = {}
    assert parse_case(two, "z.toml").schemes.nominal.k_v == 10.0  # thesis 3.3.2.3 (k4 = 10)
    for key in ("thresholds", "claims", "requirements"):  # they name schemes the narrowed run list leaves out
        two.pop(key, None)
    two["schemes"] = {"run": ["nominal", "oracle"], "oracle": {"k_v": 4.0}}
    c3 = parse_case(two, "w.toml")
    assert c3.schemes.nominal.k_v == 4.0 and c3.schemes.switching is None and c3.schemes.active_ukf is None
    two["schemes"] = {"run": ["adaptive_frozen"]}
    assert parse_case(two, "v.toml").schemes.adaptive_frozen.k_v == 10.0  # listed: the adaptive defaults
    # parsing the dump of a filled case gives the same case (the batch's workers re-parse it)
    assert parse_case(c3.model_dump(mode="json"), "w.toml") == c3


def test_expected_status_per_scheme():
    data = _base()
    data["expected_status_of"] = {"adaptive": ["ok", "step_unstable"]}
    case = parse_case(data, "x.toml")
    assert case.expected_for("adaptive") == {"ok", "step_unstable"}
    assert case.expected_for("switching") == {"ok"}  # the case-wide expected_status elsewhere


# ------------------------------------------------------------------ every error of a file (audit item 2)
def test_every_field_in_error_is_listed_once():
    data = _base()
    data["robots"]["colour"] = "red"
    data["robots"]["a"] = [0.1, -300.0, 0.1]  # the list member of a scalar-or-list field: its index, once
    data["simulation"]["dt"] = -1.0
    data["reference"]["kind"] = "circel"
    with pytest.raises(CaseError) as info:
        parse_case(data, "cases/x.toml")
    assert info.value.lines == (
        "cases/x.toml: robots.colour: unknown field",  # a typo of a key first
        "cases/x.toml: robots.a[1]: must be >= -100, got -300.0",
        "cases/x.toml: simulation.dt: must be > 0, got -1.0",
        "cases/x.toml: reference.kind: got 'circel'; expected one of 'unicycle', 'circle', 'eight', 'line', "
        "'sinusoid' (did you mean 'circle'?)",
    )
    assert str(info.value) == info.value.lines[0] + " (and 3 more; 'ftcreport cases validate' lists every one)"


def test_an_overlay_names_the_base_on_every_line(tmp_path):
    base = _base()
    base["simulation"]["dt"] = -1.0
    base["reference"]["kind"] = "circel"
    import tomli_w

    (tmp_path / "base.toml").write_text(tomli_w.dumps(base))
    (tmp_path / "over.toml").write_text('base_case = "base.toml"\n[robots]\ncolour = "red"\n')
    with pytest.raises(CaseError) as info:
        load_case(tmp_path / "over.toml")
    src, why = str(tmp_path / "over.toml"), "(the value comes from the base case base.toml)"
    assert info.value.lines[0] == f"{src}: robots.colour: unknown field"  # the overlay's own field
    assert info.value.lines[1] == f"{src}: simulation.dt: must be > 0, got -1.0 {why}"
    assert info.value.lines[2].startswith(f"{src}: reference.kind: got 'circel'") and why in info.value.lines[2]


def test_an_overlay_blames_the_base_only_for_the_base_values(tmp_path):
    """A field missing from the overlay and the base both (a motor fault's value) is the overlay's error alone."""
    (tmp_path / "base.toml").write_text((CASES / "two_link_switching.toml").read_text())
    (tmp_path / "over.toml").write_text(
        'base_case = "base.toml"\n[actuators]\n[[faults]]\ntime = 1.0\nwheel = "1r"\nmotor = "stuck"\n'
    )
    with pytest.raises(CaseError) as info:
        load_case(tmp_path / "over.toml")
    assert str(info.value) == f"{tmp_path / 'over.toml'}: faults[0].value: a motor fault 'stuck' needs a value"


# ------------------------------------------------------------------ --duration on a sampled case (session 9)
def test_a_shortened_run_keeps_the_sampling_valid():
    """``--duration`` below one sample or one delay is refused naming the option (the engine blamed dt)."""
    from ftcreport.cases import with_duration

    case = load_case(CASES / "motors" / "two_link_switching_motors.toml")  # T_s = dt = 5 ms
    with pytest.raises(CaseError) as info:
        with_duration(case, 0.003)
    assert str(info.value) == (
        "two_link_switching_motors: --duration 0.003: shorter than one control sample "
        "(simulation.sample_time = 0.005 s)"
    )
    delayed = case.model_copy(update={"simulation": case.simulation.model_copy(update={"measurement_delay": 40})})
    with pytest.raises(CaseError, match=r"--duration 0\.2: simulation\.measurement_delay: 40 sample\(s\) of 0\.005 s"):
        with_duration(delayed, 0.2)  # 40 x 5 ms = 0.2 s: the controller would see only the first sample
    short = with_duration(delayed, 0.25)
    assert (short.simulation.duration, short.simulation.dt, short.simulation.sample_time) == (0.25, 0.005, 0.005)


# ------------------------------------------------------------------ Literal fields in plain words (audit item 3)
def _literal_fields() -> list[tuple[str, str, tuple]]:
    """(model, field, allowed values) of every Literal in the case schema's models (unions and lists included)."""
    from typing import Literal, get_args, get_origin

    from pydantic import BaseModel

    from ftcreport import cases

    def literals(annotation) -> list[tuple]:
        if get_origin(annotation) is Literal:
            return [get_args(annotation)]
        return [lit for arg in get_args(annotation) for lit in literals(arg)]

    models = [m for m in vars(cases).values() if isinstance(m, type) and issubclass(m, BaseModel)]
    found = []
    for model in models:
        for name, field in model.model_fields.items():
            found += [(model.__name__, name, values) for values in literals(field.annotation)]
    return found


LITERALS = _literal_fields()


def test_the_schema_has_literal_fields():
    fields = {f"{m}.{f}" for m, f, _ in LITERALS}
    # the ones the audit met; the parametrized test below covers whatever else the schema has
    assert {"Reference.kind", "Simulation.method", "Kinematic.kind"} <= fields, fields


@pytest.mark.parametrize(("model", "field", "allowed"), LITERALS, ids=[f"{m}.{f}" for m, f, _ in LITERALS])
def test_every_literal_field_says_what_it_expects(model, field, allowed):
    """The reason of a wrong value of each Literal of the schema (pydantic's error for that Literal)."""
    from typing import Literal

    from pydantic import TypeAdapter, ValidationError

    from ftcreport.cases import Case, _message

    typo = f"{allowed[0]}x"  # one letter more than the first allowed value: difflib's closest
    with pytest.raises(ValidationError) as info:
        TypeAdapter(Literal[allowed]).validate_python(typo)
    (err,) = info.value.errors()
    msg = _message(err, Case)
    listed = ", ".join(repr(a) for a in allowed)
    assert msg == f"got '{typo}'; expected one of {listed} (did you mean '{allowed[0]}'?)", msg


def test_a_literal_typo_in_a_file():
    data = _base()
    data["simulation"]["method"] = "rk5"
    with pytest.raises(CaseError) as info:
        parse_case(data, "cases/x.toml")
    assert str(info.value) == (
        "cases/x.toml: simulation.method: got 'rk5'; expected one of 'rk4', 'ros2', 'etd2', 'auto', 'dopri5', "
        "'ros2ec', 'etd2ec', 'etd3ec', 'ros34pw2' (did you mean 'rk4'?)"
    )


def test_a_scheme_file_that_exits_on_import_is_named(tmp_path):
    """A plug-in file calling sys.exit on import ended `cases validate` with exit 3 and no message (session 9)."""
    (tmp_path / "exits_on_import_s9.py").write_text("import sys\nsys.exit(3)\n")
    data = tomllib.loads((CASES / "two_link_active.toml").read_text())
    data["plugins"] = ["exits_on_import_s9.py"]
    with pytest.raises(CaseError) as info:
        parse_case(data, str(tmp_path / "x.toml"))
    src, where = tmp_path / "x.toml", tmp_path / "exits_on_import_s9.py"
    assert str(info.value) == f"{src}: plugins[0]: {where}: the scheme file called sys.exit(3) on import"


def test_a_stored_overlay_keeps_any_text(tmp_path):
    """The stored copy of an overlay (overlay_text) read back as 'damaged' when a text held a character beyond
    U+FFFF: json.dumps wrote it as a surrogate pair, which TOML refuses (session 9 fuzzing)."""
    import tomli_w

    from ftcreport.cases import overlay_text

    text = 'astral \U0001f916 and \U0006ea22, DEL \x7f, NUL \x00, tab \t, quote " and backslash \\ end'
    data = {"base_case": str(CASES / "two_link_switching.toml"), "description": text}
    data["thresholds"] = {"switching": {"position_error_final": {"max": 1.0}}, "nëw": {"x": {"max": 2.0}}}
    (tmp_path / "over.toml").write_text(tomli_w.dumps(data))
    stored = tomllib.loads(overlay_text(tmp_path / "over.toml"))
    assert stored["description"] == text
    assert stored["thresholds"] == data["thresholds"]


def test_motors_under_rk4_at_a_step_the_currents_defeat_warn():
    """validate said nothing; every run then stopped step_unstable at t = 0.01 s (session 9 fuzzing)."""
    data = _base()  # dt = 10 ms, RK4
    data["actuators"] = {}  # the defaults: L_a / R_a = 0.161 mH / 0.365 ohm = 0.441 ms
    case = parse_case(data, "x.toml")
    # the fast root of the motor is >= R_a / (2 L_a) in magnitude: RK4 (|h lambda| <= 2.785) fails beyond 2.46 ms
    assert case.warnings()[0].startswith(
        "simulation.dt: 0.01 s with method = 'rk4' cannot integrate the armature currents of [actuators] "
        "(L_a / R_a = 0.441 ms: RK4 is unstable beyond dt = 2.46 ms for certain, likely beyond 1.23 ms)"
    )
    data["simulation"].update(dt=0.002)  # inside the certain bound: no warning (the run decides)
    assert not any("armature" in w for w in parse_case(data, "x.toml").warnings())
    data["simulation"].update(dt=0.01, method="etd2")
    assert not any("armature" in w for w in parse_case(data, "x.toml").warnings())


def test_an_unexpected_ok_names_the_field_that_expected_otherwise():
    """A run that ends 'ok' has no reason: the failure must say what the case expected, and where
    (it printed 'ok: -' before)."""
    data = _base()
    data["expected_status_of"] = {"switching": ["singular"]}
    case = parse_case(data, "cases/x.toml")
    got = case.unexpected("switching", "ok", None)
    assert got == "ok, where the case expects 'singular' (expected_status_of.switching)"
    want = " or ".join(repr(s) for s in sorted(case.expected_status))  # the file's own list (or the default)
    assert case.unexpected("nominal", "singular", "") == f"singular, where the case expects {want} (expected_status)"
    assert case.unexpected("nominal", "diverged", "|q| > 1e6 at t = 3 s") == "diverged: |q| > 1e6 at t = 3 s"


def test_every_pi_field_under_the_static_drive_is_named_at_once(tmp_path):
    """The round-3 case audit: `cases validate` named one misplaced PI field per attempt (current_kp, then
    drive_rate), and a current_bandwidth under the static drive was never named at all."""
    import tomli_w

    data = tomllib.loads((CASES / "motors" / "two_link_active_motors.toml").read_text())
    data["base_case"] = str(CASES / "two_link_active.toml")
    data["actuators"].update(current_kp=2.0, drive_rate=1000.0, current_bandwidth=500.0)
    path = tmp_path / "x.toml"
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(CaseError) as info:
        load_case(path)
    assert "actuators: current_bandwidth, current_kp, drive_rate belong to the PI drive" in str(info.value)
    data["actuators"] = {"current_bandwidth": 500.0}
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(CaseError) as info:
        load_case(path)
    assert "actuators.current_bandwidth: belongs to the PI drive" in str(info.value)


def test_an_overlay_that_changes_a_kind_takes_that_table_whole(tmp_path):
    """The review: refusing a field of another kind broke overlays that switch kinds, since TOML cannot
    delete the base's keys: two_link_active (a unicycle reference, v_d and omega_d) overlaid with an
    'eight' reference was refused on reference.v_d.  A table whose kind the overlay changes is the
    overlay's whole; one whose kind it keeps is merged key by key, as before."""
    (tmp_path / "o.toml").write_text(
        f'base_case = "{CASES / "two_link_active.toml"}"\n[reference]\nkind = "eight"\nscale = 0.5\n'
    )
    case = load_case(tmp_path / "o.toml")
    assert case.reference.kind == "eight" and case.reference.scale == 0.5 and case.reference.v_d is None
    base = load_case(CASES / "two_link_active.toml")
    (tmp_path / "k.toml").write_text(f'base_case = "{CASES / "two_link_active.toml"}"\n[kinematic]\nk1 = 3.0\n')
    same = load_case(tmp_path / "k.toml")
    assert same.kinematic.k1 == 3.0 and same.kinematic.k2 == base.kinematic.k2  # merged key by key


def test_events_are_resolved_as_finely_as_requirement_windows_take_their_edges():
    """A phase shorter than the windows' edge slack is refused (faults[i].time), so the two must agree."""
    from ftcreport.cases.case import EVENT_RESOLUTION
    from ftcreport.evaluation.requirements import EDGE_SLACK

    assert EVENT_RESOLUTION == EDGE_SLACK
    data = _base()
    data["faults"][1]["time"] = 20.0 + 2 * EDGE_SLACK  # just beyond it: a phase of its own, accepted
    parse_case(data, "cases/x.toml")
