"""Results that leave the tool: netCDF and Parquet, notebook objects, provenance manifest, cache key, JUnit."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pandas as pd
import pytest
import tomli_w
import xarray as xr
from typer.testing import CliRunner

import ftcreport
from ftcreport.cases import SCHEME_NAMES, case_hash, load_case, with_duration
from ftcreport.cli import app
from ftcreport.report.junit import junit_xml
from ftcreport.runner import expected_engine, run_scheme
from ftcreport.storage.store import save_run
from ftcreport.storage.tidy import METRICS_DTYPES, UNITS, read_run, write_metrics_parquet, write_netcdf
from ftcreport.studies.batch import record_case, run_batch, run_key
from ftcreport.studies.check import ThresholdResult, threshold_item

CASES = Path(__file__).resolve().parents[1] / "cases"
SCHEMES = ("nominal", "switching", "adaptive", "adaptive_frozen", "active", "active_ukf", "oracle")


def _fast_adaptive(tmp: Path) -> Path:
    """three_link_adaptive with its four events (frictions included) at 1, 2, 3, 4 s of a 5 s run."""
    data = tomllib.loads((CASES / "three_link_adaptive.toml").read_text())
    for f in data["faults"]:
        f["time"] = f["time"] / 20.0
    data["simulation"]["duration"] = 5.0
    path = tmp / "three_link_fast.toml"
    path.write_text(tomli_w.dumps(data))
    return path


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """two_link_active at 4 s (every kind of scheme, a fault at 0 s) and three_link_fast (four events),
    run in this process and stored as batch stores them."""
    out = tmp_path_factory.mktemp("tidy")
    runs = {}
    for path, duration in ((CASES / "two_link_active.toml", 4.0), (_fast_adaptive(out.parent), None)):
        case = load_case(path)
        if duration is not None:
            case = with_duration(case, duration)
        record_case(out, case, path, duration)
        for s in SCHEMES:
            if getattr(case.schemes, s) is None:
                continue
            run, m = run_scheme(case, s)
            save_run(out, case.name, s, run, m, run_key(case, s))
            runs[(case.name, s)] = (case, run, m)
    return out, runs


def test_netcdf_round_trip_arrays_units_fault_schedule(store, tmp_path):
    _, runs = store
    case, run, _ = runs[("three_link_fast", "adaptive")]
    path = write_netcdf(tmp_path / "run.nc", run)
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        ds = ds.load()
    # every signal comes back bit for bit, with its named dimensions and units
    np.testing.assert_array_equal(ds["time"].values, run.t)
    for name, arr in run.signals.items():
        np.testing.assert_array_equal(ds[name].values, arr, err_msg=name)
        if name in UNITS:
            assert ds[name].attrs["units"] == UNITS[name][1]
            assert ds[name].dims == ("time", *UNITS[name][0])
    assert ds["time"].attrs["units"] == "s"
    assert list(ds["wheel"].values) == ["1r", "1l", "2r", "2l", "3r", "3l"]
    assert list(ds["coordinate"].values) == ["x", "y", "theta_3", "theta_2", "theta_1"]
    assert list(ds["robot"].values) == [1, 2, 3]
    np.testing.assert_array_equal(ds["heading"].sel(robot=1).values, run["q"][:, -1])  # theta_1 is last in q
    # the fault schedule, as variables and as JSON
    events = case.faults
    assert len(events) == 4 and any(f.ubar != 0 for f in events)
    np.testing.assert_array_equal(ds["fault_time"].values, [f.time for f in events])
    assert list(ds["fault_wheel"].values) == [f.wheel for f in events]
    np.testing.assert_array_equal(ds["fault_sigma"].values, [f.sigma for f in events])
    np.testing.assert_array_equal(ds["fault_ubar"].values, [f.ubar for f in events])
    assert json.loads(ds.attrs["fault_schedule"]) == [f.model_dump(exclude={"motor", "value"}) for f in events]
    assert ds.attrs["case_hash"] == case_hash(case, ftcreport.__version__)
    assert ds.attrs["status"] == "ok" and ds.attrs["engine"] == "compiled" and ds.attrs["scheme"] == "adaptive"
    assert ds["chi_hat"].dims == ("time", "pattern", "wheel") and ds.sizes["pattern"] == len(run.meta["patterns"])


def test_stored_run_reads_back_like_the_simulated_one(store):
    out, runs = store
    case, run, m = runs[("two_link_active", "active")]
    back = read_run(out, case.name, "active")
    np.testing.assert_array_equal(back.t, run.t)
    for name, arr in run.signals.items():
        np.testing.assert_array_equal(back[name], arr, err_msg=name)
    assert back.meta["fault_schedule"] == run.meta["fault_schedule"]
    ds = back.to_xarray()
    assert list(ds["parameter"].values) == m["estimated_parameters"]  # rho_1r ... ubar_2l


def test_to_pandas_columns_and_units(store):
    _, runs = store
    _, run, _ = runs[("two_link_active", "adaptive")]
    df = run.to_pandas()
    assert df.index.name == "time" and len(df) == run.t.size
    np.testing.assert_array_equal(df["q[x]"].to_numpy(), run["q"][:, 0])
    np.testing.assert_array_equal(df["tau[2l]"].to_numpy(), run["tau"][:, 3])
    n_pat = run["chi_hat"].shape[1]
    np.testing.assert_array_equal(df[f"chi_hat[{n_pat - 1},1l]"].to_numpy(), run["chi_hat"][:, -1, 1])
    assert df.attrs["units"]["tau[2l]"] == "N m" and df.attrs["scheme"] == "adaptive"


def test_engine_in_the_cache_key_is_the_engine_that_runs(store):
    _, runs = store
    for (_, scheme), (_, _run, m) in runs.items():
        assert m["engine"] == expected_engine(scheme), scheme
    assert {m["engine"] for _, _, m in runs.values()} == {"compiled"}  # every scheme compiled (issue 20)


def test_cache_key_includes_engine_and_numeric_versions(monkeypatch):
    case = load_case(CASES / "two_link_active.toml")
    base = run_key(case, "active")
    assert run_key(case, "active") == base
    assert run_key(case, "active_ukf") != base
    import ftcreport.storage.manifest as M

    real = M.numeric_versions()
    monkeypatch.setattr(M, "numeric_versions", lambda: {**real, "numba": "0.0.1"})
    assert run_key(case, "active") != base
    monkeypatch.setattr(M, "numeric_versions", lambda: real)
    monkeypatch.setattr("ftcreport.runner.expected_engine", lambda s: "python")
    assert run_key(case, "active") != base


def test_metrics_parquet_has_the_documented_dtypes(store, tmp_path):
    out, runs = store
    path = write_metrics_parquet(out, tmp_path / "metrics.parquet")
    df = pd.read_parquet(path)
    assert list(df.columns) == list(METRICS_DTYPES)
    assert {c: str(t) for c, t in df.dtypes.items()} == {
        c: str(pd.Series([], dtype=t).dtype) for c, t in METRICS_DTYPES.items()
    }
    # one row per (case, scheme, phase): the phases of each run are those of its metrics.json
    for (name, scheme), (case, _, m) in runs.items():
        rows = df[(df["case"] == name) & (df["scheme"] == scheme)].sort_values("phase")
        assert list(rows["phase"]) == list(range(len(m["phases"])))
        assert list(rows["phase_start"]) == [p["start"] for p in m["phases"]]
        # whether the phase starts with a fault (the recovery and verdict read it; a fault at t = 0 makes
        # the first phase one): a reader filtering the table by phase had only its index to go on
        assert list(rows["phase_fault"]) == [p["fault"] for p in m["phases"]]
        at_zero = any(f.time == 0.0 for f in case.faults)  # two_link_active: yes; three_link_fast: no
        assert list(rows["phase_fault"]) == [at_zero] + [True] * (len(rows) - 1)
        assert rows["position_error_final"].iloc[0] == pytest.approx(m["position_error_final"], rel=0, abs=0)
    sw = df[(df["case"] == "three_link_fast") & (df["scheme"] == "switching")]
    assert len(sw) == 5  # four events: five phases
    assert sw["switch_count"].notna().all() and df[df["scheme"] == "nominal"]["switch_count"].isna().all()


def test_load_results_and_notebook_views(store):
    out, runs = store
    res = ftcreport.load_results(out)
    assert len(res) == len(runs) and set(zip(res["case"], res["scheme"], strict=True)) == set(runs)
    assert str(res["n_robots"].dtype) == "Int32"
    sub = res[res["scheme"] == "switching"]
    run = sub.run("two_link_active", "switching")  # the subset keeps its root: series on demand
    np.testing.assert_array_equal(run["q"], runs[("two_link_active", "switching")][1]["q"])
    html = run._repr_html_()
    assert "<svg" in html and "two_link_active / switching" in html and "compiled" in html
    case = res.case("two_link_active")
    html = case._repr_html_()
    assert html.count("<tr>") == 1 + 6 and "active_ukf" in html and "<svg" in html
    with pytest.raises(ftcreport.errors.FtcError, match="no stored run"):
        res.run("two_link_active", "nonexistent")


def test_export_command_writes_netcdf_and_parquet(store, tmp_path):
    out, runs = store
    res = CliRunner().invoke(app, ["export", "--out", str(out), "--dest", str(tmp_path / "x")])
    assert res.exit_code == 0, res.output
    assert f"{len(runs)} netCDF file(s)" in res.output
    assert (tmp_path / "x" / "metrics.parquet").exists()
    with xr.open_dataset(tmp_path / "x" / "two_link_active" / "oracle" / "timeseries.nc", engine="h5netcdf") as ds:
        assert ds.attrs["scheme"] == "oracle"
    bad = CliRunner().invoke(app, ["export", "--out", str(tmp_path / "none")])
    assert bad.exit_code == 2 and "no stored results" in bad.output


def test_batch_writes_manifest_parquet_and_page_provenance(tmp_path):
    out = tmp_path / "r"
    res = run_batch([CASES / "two_link_uncompensable.toml"], out, jobs=1, duration=1.0, show_progress=False)
    assert not res.case_errors
    m = json.loads((out / "manifest.json").read_text())
    assert m["kind"] == "batch"
    for dep in ("numba", "dask", "distributed", "slycot", "rich", "numpy", "pandas", "xarray"):
        assert m["dependencies"][dep], dep
    case = with_duration(load_case(CASES / "two_link_uncompensable.toml"), 1.0)
    assert m["cases"] == {case.name: case_hash(case, ftcreport.__version__)}
    # every family runs (issue 21); the UKF in the Python loop, the others compiled
    schemes = [s for s in SCHEME_NAMES if getattr(case.schemes, s) is not None]
    assert {(r["scheme"], r["engine"], r["key"]) for r in m["runs"]} == {
        (s, "compiled", run_key(case, s)) for s in schemes
    }
    assert m["seeds"] == {case.name: 0}
    assert pd.read_parquet(out / "metrics.parquet")["case"].unique().tolist() == [case.name]
    page = (out / case.name / "index.html").read_text()
    assert 'id="manifest"' in page and m["dependencies"]["numba"] in page and run_key(case, "switching") in page
    assert json.loads((out / case.name / "manifest.json").read_text())["kind"] == "case"


def test_junit_has_properties_time_and_timestamp():
    held = ThresholdResult("c", "switching", "position_error_final", None, 1e-3, 2e-4, True, "")
    results = [threshold_item(held, time=3.25)]
    from ftcreport.storage.manifest import build_manifest

    manifest = build_manifest("batch", cases={"c": "abc"}, runs=[{"case": "c", "scheme": "switching"}])
    xml = junit_xml(
        results,
        properties=manifest,
        time=12.5,
        timestamp="2026-11-23T10:00:00+00:00",
    )
    suite = ET.fromstring(xml)
    assert suite.get("time") == "12.500" and suite.get("timestamp") == "2026-11-23T10:00:00+00:00"
    props = {p.get("name"): p.get("value") for p in suite.find("properties")}
    assert props["dependencies.numba"] == manifest["dependencies"]["numba"]
    assert props["platform.cpu"] == manifest["platform"]["cpu"] and props["cases.c"] == "abc"
    assert json.loads(props["runs"]) == [{"case": "c", "scheme": "switching"}]
    assert suite.find("testcase").get("time") == "3.250"


def test_long_runs_are_deflated_losslessly(tmp_path):
    from ftcreport.sim import Run

    rng = np.random.default_rng(5)
    k = 600  # above the 256-sample threshold: the arrays are deflated
    sig = {"q": rng.normal(size=(k, 4)), "tau": rng.normal(size=(k, 4)), "selected": rng.integers(0, 9, size=k)}
    run = Run(t=np.linspace(0.0, 6.0, k), signals=sig, t_end=6.0, meta={"case": "c", "scheme": "switching"})
    path = write_netcdf(tmp_path / "long.nc", run)
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        assert ds["q"].encoding.get("zlib") or ds["q"].encoding.get("compression") == "gzip"
        for name, arr in sig.items():
            np.testing.assert_array_equal(ds[name].values, arr)
        assert ds.sizes["fault_event"] == 0 and ds.attrs["fault_schedule"] == "[]"


def test_run_command_writes_the_case_manifest(tmp_path):
    out = tmp_path / "r"
    args = [
        "run",
        str(CASES / "two_link_uncompensable.toml"),
        "--scheme",
        "nominal",
        "--duration",
        "1",
        "--out",
        str(out),
    ]
    res = CliRunner().invoke(app, [*args, "-q"])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "two_link_uncompensable" / "manifest.json").read_text())
    assert m["kind"] == "case" and m["settings"]["command"] == "run"
    case = with_duration(load_case(CASES / "two_link_uncompensable.toml"), 1.0)
    assert m["runs"] == [
        {
            "case": case.name,
            "scheme": "nominal",
            "engine": "compiled",
            "status": "ok",
            "cached": False,
            "key": run_key(case, "nominal"),
            "seed": 0,
            "wall_time": m["runs"][0]["wall_time"],
        }
    ]
    assert m["ftcreport"]["version"] == ftcreport.__version__


def _stored_synthetic(out: Path, scheme: str, offset: float) -> tuple[Path, str]:
    """A one-second run of two_link_uncompensable stored under ``out`` as batch stores it, its arrays shifted by
    ``offset`` (two contents of the case give two trajectories); returns its directory and case hash."""
    from ftcreport.sim import Run

    path = CASES / "two_link_uncompensable.toml"
    case = with_duration(load_case(path), 1.0)
    chash = record_case(out, case, path, 1.0)
    t = np.linspace(0.0, 1.0, 11)
    run = Run(t=t, signals={"q": np.full((11, 4), offset)}, t_end=1.0, meta={"case": case.name, "scheme": scheme})
    m = {"case": case.name, "scheme": scheme, "status": "ok", "case_hash": chash}
    return save_run(out, case.name, scheme, run, m, run_key(case, scheme)), chash


def test_a_run_stored_again_or_removed_leaves_no_netcdf_of_the_run_before(tmp_path):
    """export's timeseries.nc beside a run is of that run: a batch storing the run again (the case edited) or
    removing it (a scheme dropped) left it there, with the old case hash, status and trajectory."""
    from ftcreport.storage.store import remove_run
    from ftcreport.storage.tidy import export

    out = tmp_path / "r"
    d, _ = _stored_synthetic(out, "nominal", 0.0)
    export(out)
    assert (d / "timeseries.nc").exists()
    _stored_synthetic(out, "nominal", 1.0)  # stored again: the netCDF of the run before goes with it
    assert not (d / "timeseries.nc").exists(), "timeseries.nc of the previous run left beside the new one"
    export(out)
    with xr.open_dataset(d / "timeseries.nc", engine="h5netcdf") as ds:
        np.testing.assert_array_equal(ds["q"].values, np.full((11, 4), 1.0))
    remove_run(out, d.parent.name, "nominal")  # removed: nothing of it stays, its directory neither
    assert not d.exists()


def test_export_removes_the_netcdf_of_a_run_it_skips(tmp_path):
    """A damaged run gets no netCDF: the one an earlier export wrote for it (beside it or in --dest) was left,
    still saying status ok."""
    from ftcreport.storage.tidy import export

    out, dest = tmp_path / "r", tmp_path / "x"
    d, _ = _stored_synthetic(out, "nominal", 0.0)
    export(out)
    export(out, dest)
    (d / "metrics.json").write_text((d / "metrics.json").read_text().replace('"ok"', '"error"'))
    for where in (None, dest):
        damaged: list[str] = []
        export(out, where, damaged)
        assert damaged and "metrics.json: " in damaged[0]
        assert not ((where or out) / d.parent.name / "nominal" / "timeseries.nc").exists(), where


@pytest.mark.parametrize(
    ("drive", "states"),
    [({}, ()), ({"driver": "pi"}, ("z",)), ({"driver": "pi", "drive_rate": 200.0}, ("z", "v_held"))],
    ids=["static", "pi", "pi_sampled"],
)
def test_netcdf_of_a_motor_case_has_currents_per_wheel_in_amperes(tmp_path, drive, states):
    """W4 (newuser12): on two_link_switching_motors the export's ``i_a`` had dims ('time', 'i_a_dim1') and
    units 'unknown', and ``xc`` only the units 'mixed', though the README promises units in each
    variable's attributes and a ``wheel`` dimension.  The currents lie along ``wheel`` in A; a PI drive's
    states (its integral part z, and the sampled PI's held voltage, both in V) along ``drive_state``, each
    column named and tied to its wheel; ``xc`` says why its units are mixed."""
    data = tomllib.loads((CASES / "motors" / "two_link_switching_motors.toml").read_text())
    data["base_case"] = str((CASES / "two_link_switching.toml").resolve())
    data["actuators"] = data.get("actuators", {}) | drive
    path = tmp_path / "motors.toml"
    path.write_text(tomli_w.dumps(data))
    run, _ = run_scheme(with_duration(load_case(path), 0.1), "switching")
    with xr.open_dataset(write_netcdf(tmp_path / "run.nc", run), engine="h5netcdf") as ds:
        ds = ds.load()
    wheels = ["1r", "1l", "2r", "2l"]
    assert ds["i_a"].dims == ("time", "wheel") and list(ds["wheel"].values) == wheels
    assert ds["i_a"].attrs["units"] == "A" and "armature current" in ds["i_a"].attrs["long_name"]
    np.testing.assert_array_equal(ds["i_a"].values, run["i_a"])
    assert np.abs(ds["i_a"].values).max() > 0.1  # a real current [A], not an empty column
    if not states:
        assert "z_drive" not in ds and "drive_state" not in ds.dims
    else:
        assert ds["z_drive"].dims == ("time", "drive_state") and ds["z_drive"].attrs["units"] == "V"
        assert list(ds["drive_state"].values) == [f"{s}_{w}" for s in states for w in wheels]
        assert list(ds["wheel_of_drive_state"].values) == wheels * len(states)
        np.testing.assert_array_equal(ds["z_drive"].values, run["z_drive"])
    assert ds["xc"].attrs["units"] == "mixed"
    assert "controller" in ds["xc"].attrs["long_name"] and "units" in ds["xc"].attrs["description"]
    assert not [k for k, v in ds.variables.items() if v.attrs.get("units") == "unknown"]
    assert not [d for d in ds.dims if "_dim" in d]
