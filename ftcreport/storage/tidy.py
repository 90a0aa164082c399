"""Tidy views of results: xarray Datasets, pandas DataFrames, netCDF and Parquet files.

A :class:`~ftcreport.sim.Run` becomes an ``xarray.Dataset`` with named dimensions

* ``time`` [s] (the logged instants),
* ``coordinate`` (``x, y, theta_n, ..., theta_1``: the order of q),
* ``velocity`` (``v_n, omega_1``: the order of eta),
* ``wheel`` (``1r, 1l, ..., nr, nl``) with the auxiliary coordinate ``robot_of_wheel``,
* ``drive_state`` (a case with PI drives: ``z_1r, ..., z_nl``, the PI's integral part per wheel, then
  for a sampled PI ``v_held_1r, ..., v_held_nl``, its held voltage; both in V, the motor states after
  the currents ``i_a`` of ``model.drive_compiled``) with the auxiliary coordinate ``wheel_of_drive_state``,
* ``robot`` (1..n, leader first) for the derived ``heading``,
* ``parameter`` (the estimated gains and frictions of an active scheme),
* ``pattern`` (the models of the switching and adaptive schemes),

units in each variable's ``units`` attribute, and as metadata the case, the scheme, the case
content hash (the result cache key), the status and reason, the engine, and the fault schedule
(both as the ``fault_*`` variables along ``fault_event`` and as the JSON attribute
``fault_schedule``).  :func:`write_netcdf` stores it (h5netcdf); :func:`read_run` reads a stored
run back.  :func:`metrics_table` gives the batch's metrics, one row per (case, scheme, phase), with
the dtypes of :data:`METRICS_DTYPES`; :func:`write_metrics_parquet` stores it as
``metrics.parquet`` beside the JSON.  :func:`export` does both for a whole output directory
(``ftcreport export``).

pandas and xarray are imported inside the functions: the numeric core does not load them.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..model.faults import wheel_names

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd
    import xarray as xr

    from ..sim import Run

__all__ = [
    "METRICS_DTYPES",
    "UNITS",
    "export",
    "metrics_table",
    "read_run",
    "run_dataset",
    "run_frame",
    "write_metrics_parquet",
    "write_netcdf",
]

_Q = "m (x, y), rad (theta_i)"
_ETA = "m/s (v_n), rad/s (omega_1)"
#: signal name -> (dimensions after time, units, long name); others get generic dimensions.
UNITS: dict[str, tuple[tuple[str, ...], str, str]] = {
    "q": (("coordinate",), _Q, "configuration q = [x, y, theta_n, ..., theta_1]"),
    "q_d": (("coordinate",), _Q, "reference configuration"),
    "q_hat": (("coordinate",), _Q, "estimated configuration"),
    "q_meas": (("coordinate",), _Q, "measured configuration (with sensor noise)"),
    "eta": (("velocity",), _ETA, "velocities eta = [v_n, omega_1]"),
    "eta_c": (("velocity",), _ETA, "velocity command of the kinematic controller"),
    "eta_c_dot": (("velocity",), "m/s^2 (v_n), rad/s^2 (omega_1)", "derivative of the velocity command"),
    "eta_d": (("velocity",), _ETA, "reference velocities"),
    "eta_hat": (("velocity",), _ETA, "estimated velocities"),
    "u": (("wheel",), "N m", "commanded torque"),
    "tau": (("wheel",), "N m", "applied torque tau = sigma sat(u) + ubar"),
    "sigma": (("wheel",), "1", "true effectiveness"),
    "ubar": (("wheel",), "N m", "true additive friction"),
    "sigma_used": (("wheel",), "1", "effectiveness the law uses"),
    "ubar_used": (("wheel",), "N m", "friction the law uses"),
    "rho_hat": (("wheel",), "1", "estimated effectiveness"),
    "ubar_hat": (("wheel",), "N m", "estimated friction"),
    "uf_hat": (("wheel",), "N m", "friction estimate of the adaptive law (a control variable)"),
    "param_std": (("parameter",), "1 (rho), N m (ubar)", "standard deviation of the estimated parameters"),
    "P_max": ((), "1", "largest entry of the observer's P"),
    "selected": ((), "1", "index of the applied model"),
    "cost": (("pattern",), "(m/s)^2", "switching cost of every model"),
    "cost_selected": ((), "(m/s)^2", "switching cost of the applied model (banks too large to log every cost)"),
    "cost_best": ((), "(m/s)^2", "least switching cost of the bank (banks too large to log every cost)"),
    "chi_hat": (("pattern", "wheel"), "1", "adaptive weights"),
    "z": (("chained",), "chained-form coordinates", "chained-form coordinates of the kinematic controller"),
    "xc": (("controller_state",), "mixed", "controller state: the control law's internal states"),
    "i_a": (("wheel",), "A", "armature current of each wheel's motor"),
    "tau_mid": (("wheel",), "N m", "applied torque at each step's midpoint (the energy's quadrature with motors)"),
    "z_drive": (("drive_state",), "V", "the PI drives' states: integral part z per wheel, then a sampled PI's held v"),
}
#: what a variable's units attribute cannot say (its ``description``)
DESCRIPTIONS = {
    "xc": "the scheme's own states (observer, adaptation, switching cost filters...) side by side, each in its "
    "own units, so the column units are mixed; the ones a report reads are logged again by name with their "
    "units (rho_hat, ubar_hat, chi_hat, cost, ...)",
}
#: the motor states a PI drive adds after the currents, in this order per wheel (model.drive_compiled)
DRIVE_STATES = ("z", "v_held")


def _labels(n: int) -> dict[str, list[str]]:
    return {
        "coordinate": ["x", "y", *[f"theta_{i}" for i in range(n, 0, -1)]],
        "velocity": ["v_n", "omega_1"],
        "wheel": list(wheel_names(n)),
    }


def _n_robots(run: Run) -> int:
    if "q" in run.signals:
        return int(run.signals["q"].shape[1]) - 2
    return int(run.meta.get("n_robots", 0))


def run_dataset(run: Run) -> xr.Dataset:
    """The run as an ``xarray.Dataset`` (see the module docstring for dimensions and metadata).

    ``run.meta`` supplies what the arrays do not carry: ``case``, ``scheme``, ``case_hash``,
    ``engine``, ``fault_schedule`` (list of {time, wheel, sigma, ubar}), ``estimated_parameters``,
    ``patterns``; runs made by :func:`ftcreport.runner.run_scheme` or read by :func:`read_run` have them.
    """
    import xarray as xr

    n = _n_robots(run)
    labels = _labels(n) if n > 0 else {}
    meta = run.meta
    data_vars: dict[str, Any] = {}
    coords: dict[str, Any] = {"time": ("time", np.asarray(run.t, dtype=float), {"units": "s", "long_name": "time"})}
    sizes: dict[str, int] = {}
    for name, arr in run.signals.items():
        arr = np.asarray(arr)
        known = UNITS.get(name)
        generic = tuple(f"{name}_dim{i}" for i in range(1, arr.ndim))
        dims = known[0] if known is not None and len(known[0]) == arr.ndim - 1 else generic
        if any(sizes.get(d, size) != size for d, size in zip(dims, arr.shape[1:], strict=True)):
            dims = generic  # a signal whose width differs from the shared dimension
        sizes.update(zip(dims, arr.shape[1:], strict=True))
        attrs = {"units": known[1], "long_name": known[2]} if known is not None else {"units": "unknown"}
        if name in DESCRIPTIONS:
            attrs["description"] = DESCRIPTIONS[name]
        data_vars[name] = (("time", *dims), arr, attrs)
    for dim, labs in labels.items():
        if sizes.get(dim) == len(labs):
            coords[dim] = (dim, labs)
    if "wheel" in coords:
        coords["robot_of_wheel"] = ("wheel", np.repeat(np.arange(1, n + 1), 2), {"long_name": "robot of the wheel"})
    k = sizes.get("drive_state", 0) // max(len(labels.get("wheel", [])), 1)
    if 0 < k <= len(DRIVE_STATES) and sizes["drive_state"] == k * len(labels["wheel"]):
        # each wheel's states in the drives' order: z of every wheel, then the sampled PI's held voltage
        coords["drive_state"] = ("drive_state", [f"{d}_{w}" for d in DRIVE_STATES[:k] for w in labels["wheel"]])
        coords["wheel_of_drive_state"] = ("drive_state", labels["wheel"] * k, {"long_name": "wheel of the drive state"})
    if "coordinate" in coords:
        units = ["m", "m"] + ["rad"] * n
        coords["coordinate_unit"] = ("coordinate", units)
    if "q" in run.signals and n > 0:
        heading = np.asarray(run.signals["q"])[:, 2:][:, ::-1]  # theta_1..theta_n
        data_vars["heading"] = (("time", "robot"), heading, {"units": "rad", "long_name": "heading of robot i"})
        coords["robot"] = ("robot", np.arange(1, n + 1), {"long_name": "robot (1 = leader)"})
    params = meta.get("estimated_parameters")
    if params and sizes.get("parameter") == len(params):
        coords["parameter"] = ("parameter", list(params))
    patterns = meta.get("patterns")
    if patterns is not None and sizes.get("pattern") == len(patterns):
        coords["pattern"] = ("pattern", np.arange(len(patterns)))
        coords["pattern_failed"] = (
            "pattern",
            [",".join(w for w, s in zip(labels.get("wheel", []), p, strict=False) if s == 0) for p in patterns],
            {"long_name": "wheels the model assumes failed"},
        )
    faults = list(meta.get("fault_schedule") or [])
    data_vars["fault_time"] = (("fault_event",), np.array([f["time"] for f in faults], dtype=float), {"units": "s"})
    data_vars["fault_wheel"] = (("fault_event",), np.array([str(f["wheel"]) for f in faults], dtype=str))
    data_vars["fault_sigma"] = (("fault_event",), np.array([f["sigma"] for f in faults], dtype=float), {"units": "1"})
    data_vars["fault_ubar"] = (("fault_event",), np.array([f["ubar"] for f in faults], dtype=float), {"units": "N m"})
    attrs = {
        "title": f"ftcreport run {meta.get('case', '?')} / {meta.get('scheme', '?')}",
        "case": str(meta.get("case", "")),
        "scheme": str(meta.get("scheme", "")),
        "case_hash": str(meta.get("case_hash", "")),
        "status": run.status,
        "reason": run.reason,
        "t_end": float(run.t_end),
        "steps": int(run.steps),
        "wall_time": float(run.wall_time),
        "engine": str(meta.get("engine", "python")),
        "n_robots": n,
        "fault_schedule": json.dumps(faults),
        "package_version": str(meta.get("package_version", "")),
    }
    for key in ("dt", "duration", "log_every"):
        if key in meta:
            attrs[key] = meta[key]
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def run_frame(run: Run) -> pd.DataFrame:
    """The run as a wide ``pandas.DataFrame``: index ``time`` [s], one column per signal component.

    Columns are ``name[label]`` (``q[x]``, ``tau[2l]``, ``chi_hat[3,1r]``); a scalar signal keeps its
    name.  ``df.attrs`` holds the metadata and ``df.attrs["units"]`` the unit of every column.
    """
    import pandas as pd

    ds = run_dataset(run)
    cols: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for name, var in ds.data_vars.items():
        if var.dims[:1] != ("time",):
            continue
        arr = var.values.reshape(var.shape[0], -1)
        if var.ndim == 1:
            keys = [name]
        else:
            axes = [
                [str(v) for v in ds[d].values] if d in ds.coords else [str(i) for i in range(ds.sizes[d])]
                for d in var.dims[1:]
            ]
            keys = [f"{name}[{','.join(c)}]" for c in itertools.product(*axes)]
        for k, col in zip(keys, arr.T, strict=True):
            cols[k] = col
            units[k] = var.attrs.get("units", "")
    df = pd.DataFrame(cols, index=pd.Index(ds["time"].values, name="time"))
    df.attrs = {**{k: v for k, v in ds.attrs.items()}, "units": units}
    return df


def write_netcdf(path: Path, run: Run) -> Path:
    """Store the run's Dataset as netCDF-4 (h5netcdf, deflated), atomically."""
    from .store import write_atomic

    ds = run_dataset(run)
    # deflate the numeric arrays of a long run (Table 4.2, 2001 samples: 2.9 MB instead of 3.5 MB; the
    # .npz is 2.6 MB); a short run's arrays are smaller than the chunk and filter overhead
    enc = {}
    if ds.sizes.get("time", 0) >= 256:
        enc = {k: {"zlib": True, "complevel": 4} for k, v in ds.variables.items() if v.dtype.kind in "fiu" and v.size}
    data = ds.to_netcdf(engine="h5netcdf", encoding=enc)
    write_atomic(Path(path), bytes(data))
    return Path(path)


def read_run(out: Path, case: str, scheme: str) -> Run | None:
    """A stored run (``<out>/<case>/<scheme>/``) as a :class:`Run` with its metadata, or None."""
    from ..errors import FtcError
    from ..sim import Run
    from .store import load_metrics, load_stored_case, load_timeseries, read_json

    out = Path(out)
    ts = load_timeseries(out, case, scheme)
    m = load_metrics(out, case, scheme)
    if ts is None or m is None:
        return None
    t = ts.pop("t")
    meta: dict[str, Any] = {
        "case": case,
        "scheme": scheme,
        "engine": m.get("engine", "python"),
        "dt": m.get("dt"),
        "duration": m.get("duration"),
        "n_robots": m.get("n_robots"),
        "package_version": m.get("package_version", ""),
        "estimated_parameters": m.get("estimated_parameters") or None,  # None: dropped below
        "patterns": m.get("patterns"),
        "case_hash": m.get("case_hash", ""),
    }
    toml = out / case / "case.toml"
    rec = read_json(out / case / "case.json")
    if toml.exists():
        try:
            if not isinstance(rec, dict):
                raise FtcError(f"{out / case / 'case.json'}: not a case record")
            # the case its runs were made from, or none (export names an edited one: store.edited_cases)
            c = load_stored_case(out, case, rec)
            meta["fault_schedule"] = [
                {k: v for k, v in f.model_dump().items() if k not in ("motor", "value") or f.motor is not None}
                for f in c.faults
                if f.time < (m.get("duration") or math.inf)
            ]
        except Exception:  # a record whose case no longer validates still gives its arrays
            meta["fault_schedule"] = []
    meta = {k: v for k, v in meta.items() if v is not None}
    return Run(
        t=t,
        signals=ts,
        status=m.get("status", "ok"),
        reason=m.get("reason", "") or "",
        t_end=float(m.get("t_end") or (t[-1] if t.size else 0.0)),
        wall_time=float(m.get("wall_time") or 0.0),
        meta=meta,
    )


#: Columns of metrics.parquet and their pandas dtypes (nullable where a run may lack the value).
METRICS_DTYPES: dict[str, str] = {
    "case": "string",
    "scheme": "string",
    "phase": "Int32",  # 0 for the interval before the first event; <NA> for a run without phases
    "phase_start": "float64",  # [s]
    "phase_end": "float64",  # [s]
    "phase_fault": "boolean",  # the phase starts with a fault event (the first one too for a fault at t = 0)
    "phase_position_error_max": "float64",  # [m]
    "phase_position_error_rms": "float64",  # [m]
    "phase_position_error_final": "float64",  # [m]
    "phase_position_error_iae": "float64",  # [m s]
    "phase_recovery_time": "float64",  # [s]; NaN when the error never re-enters the band
    "status": "string",
    "reason": "string",
    # the case file was rejected by the last batch that read it: the run is of an earlier version of the file
    # (the index leaves it out: report.render.stale_runs' rule, the case record's status "error")
    "stale": "boolean",
    "engine": "string",
    "case_hash": "string",
    "n_robots": "Int32",
    "reference_kind": "string",
    "method": "string",
    "dt": "float64",  # [s]
    "duration": "float64",  # [s]
    "t_end": "float64",  # [s]
    "position_error_max": "float64",  # [m]
    "position_error_final": "float64",  # [m]
    "position_error_rms": "float64",  # [m]
    "position_error_iae": "float64",  # [m s]
    "heading_error_max": "float64",  # [rad]
    "heading_error_final": "float64",  # [rad]
    "recovery_time_max": "float64",  # [s]
    "torque_peak": "float64",  # [N m]
    "torque_peak_after_fault": "float64",  # [N m], from the first fault on
    "torque_rms": "float64",  # [N m]
    "saturation_fraction": "float64",
    "energy": "float64",  # [J]
    "singularity_margin_min": "float64",  # [rad]
    "switch_count": "Int32",
    "switching_match_fraction": "float64",
    "detection_delay_max": "float64",  # [s]
    "missed_detections": "Int32",
    "false_alarms": "Int32",
    "wall_time": "float64",  # [s], compile_time included
    "compile_time": "float64",  # [s], compiling or loading the engine's loop in the run's process
    "package_version": "string",
}


_PHASE_COLUMNS = [c for c in METRICS_DTYPES if c.startswith("phase_")]  # phase_start <- the phase's "start", ...


def _phase_rows(m: dict, key: str) -> list[dict]:
    base = {c: m.get(c) for c in METRICS_DTYPES if not c.startswith("phase")}
    base["case_hash"] = m.get("case_hash") or key
    phases = m.get("phases") or []
    if not phases:
        return [base | {"phase": None}]
    return [
        base | {"phase": i} | {c: p.get(c.removeprefix("phase_")) for c in _PHASE_COLUMNS} for i, p in enumerate(phases)
    ]


def metrics_table(out: Path) -> pd.DataFrame:
    """Every stored run's metrics under ``out``: one row per (case, scheme, phase), :data:`METRICS_DTYPES`."""
    import pandas as pd

    from .store import read_json, stored_runs

    out = Path(out)
    rows: list[dict] = []
    for rec in sorted(out.glob("*/case.json")):
        name = rec.parent.name
        record = read_json(rec)
        if not isinstance(record, dict):  # not a case record: export names it (store.unrecorded_cases)
            continue
        stale = record.get("status") == "error"
        for s, run in stored_runs(out, name).items():  # a damaged run is a row with status error, not left out
            key = (run.record or {}).get("key") or ""
            rows += _phase_rows({"case": name, "scheme": s} | run.shown() | {"stale": stale}, key)
    df = pd.DataFrame(rows, columns=list(METRICS_DTYPES))
    for col, dtype in METRICS_DTYPES.items():
        if dtype == "float64":
            df[col] = pd.to_numeric(df[col], errors="coerce").astype("float64")
        else:
            df[col] = df[col].astype(dtype)
    return df


def table_inputs(out: Path) -> str:
    """A digest of what :func:`metrics_table` reads: every case record and run record under ``out`` (each
    run record holds its files' hashes), by path and content."""
    import hashlib

    out = Path(out)
    h = hashlib.sha256()
    for p in sorted([*out.glob("*/case.json"), *out.glob("*/*/record.json")]):
        h.update(p.relative_to(out).as_posix().encode() + b"\0")
        try:
            h.update(p.read_bytes())
        except OSError:
            h.update(b"<unreadable>")
        h.update(b"\0")
    return h.hexdigest()


def table_stale(out: Path, path: Path | None = None) -> bool:
    """The table at ``path`` (default ``<out>/metrics.parquet``) is missing, damaged (not the bytes its stamp
    names) or of other inputs than the stored runs now (:func:`table_inputs`): by content, not by date."""
    import hashlib
    import json

    out = Path(out)
    path = Path(path) if path is not None else out / "metrics.parquet"
    try:
        stamp = json.loads(path.with_name(path.name + ".stamp").read_text())
        blob = path.read_bytes()
    except (OSError, ValueError):
        return True
    if not isinstance(stamp, dict) or stamp.get("sha256") != hashlib.sha256(blob).hexdigest():
        return True
    return stamp.get("inputs") != table_inputs(out)


def write_metrics_parquet(out: Path, path: Path | None = None) -> Path:
    """``metrics.parquet`` (pyarrow) beside the runs' JSON, atomically, and its stamp (``.stamp``: the
    table's sha256 and its inputs' digest, :func:`table_stale`); returns its path."""
    import hashlib
    import io
    import json

    from .store import write_atomic

    out = Path(out)
    path = Path(path) if path is not None else out / "metrics.parquet"
    inputs = table_inputs(out)
    buf = io.BytesIO()
    metrics_table(out).to_parquet(buf, engine="pyarrow", index=False)
    blob = buf.getvalue()
    write_atomic(path, blob)
    stamp = {"sha256": hashlib.sha256(blob).hexdigest(), "inputs": inputs}
    write_atomic(path.with_name(path.name + ".stamp"), json.dumps(stamp).encode())
    return path


def export(out: Path, dest: Path | None = None, damaged: list[str] | None = None) -> list[Path]:
    """netCDF of every stored run (``<dest>/<case>/<scheme>/timeseries.nc``) and ``<dest>/metrics.parquet``.

    ``dest`` defaults to ``out`` (the files go beside the JSON and ``.npz``).  A damaged stored run
    (:func:`ftcreport.storage.store.check_run`) gets no netCDF and is a row with status ``error`` in the table;
    its problem (``<file>: <why>``) is appended to ``damaged`` when given.  The netCDF an earlier export wrote
    for it is removed: it would stand in ``dest`` as the run's, status ok, while the run is not exported.
    """
    from ..errors import FtcError
    from .store import NETCDF, check_inside, read_json, stored_runs

    out = Path(out)
    dest = Path(dest) if dest is not None else out
    if not out.is_dir() or not (any(out.glob("*/case.json")) or any(out.glob("*/*/record.json"))):
        raise FtcError(f"{out}: no stored results (run 'ftcreport batch' first)")
    written = []
    for rec in sorted(out.glob("*/case.json")):
        name = rec.parent.name
        if not isinstance(read_json(rec), dict):  # not a case record: named by the caller (unrecorded_cases)
            continue
        for s, stored in stored_runs(out, name).items():
            run = read_run(out, name, s) if stored.sound else None
            nc = dest / name / s / NETCDF
            if run is None:
                if not stored.sound and damaged is not None:
                    damaged.append(stored.problem)
                check_inside(nc)  # as a write: never through a link out of the directory
                nc.unlink(missing_ok=True)
                continue
            written.append(write_netcdf(nc, run))
    written.append(write_metrics_parquet(out, dest / "metrics.parquet"))
    return written
