r"""Evaluation of fault detection and isolation (FDI) over noisy campaign samples (issue 22).

Two detectors run on the logged traces of an active scheme (Farza observer or UKF):

* **estimate-based**: parameter j is in alarm while its estimate differs from the
  nominal value (gain 1, friction 0) by more than a threshold (``c`` for gains,
  ``2 c`` for frictions, the ratio of the diagnosis bands) for ``dwell`` seconds
  in a row (:func:`threshold_state`); isolation names the parameter (wheel and kind)
  whose alarm comes first.
* **residual-based**: the combined-effect residual
  ``r = Mbar1^-1 Bbar (u - (diag(rho_hat) u + ubar_hat))``: the acceleration deficit
  of the actuators the estimator sees against healthy wheels (ERRATA P3: the
  combined effect is what the measurements determine), normalised per component
  by its standard deviation over a fault-free calibration window, ``z = |r / s|``,
  fed to a one-sided CUSUM ``S_k = max(0, S_(k-1) + z_k - mean_0 - drift)`` that
  alarms and resets when ``S_k > h`` (:func:`cusum_state`).  Isolation: the wheel
  and kind whose signature direction in the 2-D acceleration space
  (``Mbar1^-1 Bbar e_j u_j`` for a gain loss, ``Mbar1^-1 Bbar e_j`` for a friction)
  is best aligned with the mean residual just before the alarm.

Scoring (:func:`score`), own to this module (``ftcreport.evaluation.diagnosis`` keeps its own):
time before the first fault (after ``skip`` seconds of start-up) is fault-free; a
rising edge of the alarm state there is a false alarm; the fault is detected when
the alarm state is on at some instant at or after its onset, the delay is that
instant minus the onset.  Over samples: detection probability, false alarms per
hour of fault-free time, mean delay, isolation accuracy (right wheel and kind among
the sample's faults).  Sweeping the threshold (and dwell, or h) gives the ROC.

Everything but :func:`fdi_traces` (which simulates) is pure.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np

from .. import __version__
from ..errors import FtcError
from ..schemes import built_in
from ..storage.store import locked

__all__ = [
    "cusum_state",
    "fdi_traces",
    "roc",
    "score",
    "sweep_fdi",
    "threshold_state",
]


# ---------------------------------------------------------------------- detectors (pure)
def threshold_state(x: np.ndarray, threshold: float, dwell_n: int) -> np.ndarray:
    """Alarm state: ``|x| > threshold`` for at least ``dwell_n`` consecutive samples (x: (K,) or (K, p) any)."""
    x = np.abs(np.asarray(x, dtype=float))
    over = x > threshold
    if over.ndim == 1:
        over = over[:, None]
    run = np.zeros(over.shape[1], dtype=int)
    state = np.zeros(over.shape, dtype=bool)
    for k in range(over.shape[0]):
        run = np.where(over[k], run + 1, 0)
        state[k] = run >= max(1, int(dwell_n))
    return state


def cusum_state(z: np.ndarray, drift: float, h: float) -> np.ndarray:
    """One-sided CUSUM with reset: True at the samples where ``S_k > h`` (then ``S`` restarts at 0)."""
    z = np.asarray(z, dtype=float)
    out = np.zeros(z.size, dtype=bool)
    S = 0.0
    for k in range(z.size):
        S = max(0.0, S + z[k] - drift)
        if h < S:
            out[k] = True
            S = 0.0
    return out


def score(t: np.ndarray, state: np.ndarray, t_fault: float | None, skip: float = 0.0) -> dict:
    """False alarms before the fault and detection at or after it (see the module docstring).

    ``state`` is (K,) (any column of (K, p) counts).  Returns ``false_alarms``,
    ``free_time`` [s], ``detected``, ``delay`` [s] and ``first`` (index of the detection).
    """
    t = np.asarray(t, dtype=float)
    st = np.asarray(state, dtype=bool)
    anyst = st.any(axis=1) if st.ndim == 2 else st
    end = t[-1] if t_fault is None else t_fault
    free = (t >= skip) & (t < end)
    rising = anyst & ~np.concatenate(([False], anyst[:-1]))
    # a state already on when the fault-free window opens counts as one false alarm
    first_free = np.argmax(free) if free.any() else None
    fa = int(np.sum(rising & free)) + int(first_free is not None and anyst[first_free] and not rising[first_free])
    out = {
        "false_alarms": fa,
        "free_time": float(max(0.0, end - skip)),
        "detected": False,
        "delay": None,
        "first": None,
    }
    if t_fault is not None:
        after = np.nonzero(anyst & (t >= t_fault))[0]
        if after.size:
            out |= {"detected": True, "delay": float(t[after[0]] - t_fault), "first": int(after[0])}
    return out


def roc(segments: Sequence[dict], detector, settings: Sequence, skip: float = 0.0) -> list[dict]:
    """ROC points: for each setting ``s``, ``detector(segment, s) -> state`` scored over all segments.

    A segment is ``{"t", "t_fault", ...}`` (the detector reads what it needs).  Each point:
    ``setting``, ``pd`` (detected / segments with a fault), ``far_per_hour`` (false alarms per
    hour of fault-free time), ``mean_delay`` [s] (over detected), ``n``.
    """
    out = []
    for s in settings:
        det, n_fault, fa, free, delays = 0, 0, 0, 0.0, []
        for seg in segments:
            sc = score(seg["t"], detector(seg, s), seg["t_fault"], skip)
            fa += sc["false_alarms"]
            free += sc["free_time"]
            if seg["t_fault"] is not None:
                n_fault += 1
                if sc["detected"]:
                    det += 1
                    delays.append(sc["delay"])
        out.append(
            {
                "setting": s,
                "pd": det / n_fault if n_fault else None,
                "far_per_hour": 3600.0 * fa / free if free > 0 else None,
                "mean_delay": float(np.mean(delays)) if delays else None,
                "n": len(segments),
            }
        )
    return out


# ---------------------------------------------------------------------- traces (simulation, worker side)
def fdi_traces(base_json: str, index: int, campaign_seed: int, scheme: str, calibration: tuple[float, float]) -> dict:
    """Run one campaign sample with an active ``scheme``; the traces the detectors need (JSON-able).

    ``calibration``: the fault-free window [s] where the residual's scale is estimated.
    """
    from ..cases import parse_case
    from ..evaluation.diagnosis import combined_effect, input_matrices
    from ..model import wheel_names
    from ..runner import build, make_controller
    from ..sim import simulate
    from .campaign import campaign_hash, case_content_hash, draw_variant, identity, sample_seeds

    base = parse_case(json.loads(base_json), "fdi base")
    seeds = sample_seeds(campaign_seed, index)
    variant = draw_variant(base, seeds)
    built = build(variant)
    ctrl = make_controller(built, scheme)
    run = simulate(built.plant, ctrl, built.q0, built.eta0, built.settings)
    t = run.t
    names = list(ctrl.est.parameter_names())
    wn = list(wheel_names(variant.robots.n))
    est = {f"rho_{w}": run["rho_hat"][:, i] for i, w in enumerate(wn)} | {
        f"ubar_{w}": run["ubar_hat"][:, i] for i, w in enumerate(wn)
    }
    u = (
        run["u"]
        if variant.plant.saturation is None
        else np.clip(run["u"], -variant.plant.saturation, variant.plant.saturation)
    )
    MB = input_matrices(built.chain, run["q"])
    ones, zeros = np.ones_like(u), np.zeros_like(u)
    r = combined_effect(MB, u, ones, zeros) - combined_effect(MB, u, run["rho_hat"], run["ubar_hat"])
    cal = (t >= calibration[0]) & (t < calibration[1])
    if cal.sum() < 5:
        raise FtcError(f"fdi calibration window {calibration} s holds fewer than 5 logged samples")
    s = r[cal].std(axis=0) + 1e-12
    z = np.linalg.norm(r / s, axis=1)
    faults = [f.model_dump() for f in variant.faults]
    return {
        "sample": int(index),
        "scheme": scheme,
        "version": __version__,
        **identity(),
        "case_hash": case_content_hash(base),
        "campaign": campaign_hash(base, [scheme], campaign_seed),
        "status": run.status,
        "t": t.tolist(),
        "names": names,
        "estimates": {k: est[k].tolist() for k in names},
        "z": z.tolist(),
        "z_mean0": float(z[cal].mean()),
        "residual": r.tolist(),
        "signatures": _signatures(MB, u).tolist(),
        "faults": faults,
        "t_fault": min(f["time"] for f in faults) if faults else None,
    }


def _signatures(MB: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(K, 2 p, 2) signature directions: gain loss of wheel j (MB e_j u_j), then friction (MB e_j)."""
    gain = np.einsum("kij,kj->kji", MB, u)
    fric = np.transpose(MB, (0, 2, 1))
    return np.concatenate([gain, fric], axis=1)


# ---------------------------------------------------------------------- sweeps (pure)
def _truth(faults: list[dict]) -> set[tuple[str, str]]:
    out = set()
    for f in faults:
        if f["sigma"] < 1.0:
            out.add((f["wheel"], "gain"))
        if f["ubar"] != 0.0:
            out.add((f["wheel"], "friction"))
    return out


def _estimate_state(seg: dict, setting: tuple[float, float]) -> np.ndarray:
    c, dwell = setting
    t = np.asarray(seg["t"])
    dt = float(np.median(np.diff(t)))
    cols = []
    for name in seg["names"]:
        x = np.asarray(seg["estimates"][name]) - (1.0 if name.startswith("rho_") else 0.0)
        cols.append(threshold_state(x, c if name.startswith("rho_") else 2.0 * c, round(dwell / dt) + 1)[:, 0])
    return np.stack(cols, axis=1)


def _cusum(seg: dict, setting: tuple[float, float]) -> np.ndarray:
    h, drift = setting
    return cusum_state(np.asarray(seg["z"]) - seg["z_mean0"], drift, h)


def _isolated_estimate(seg: dict, state: np.ndarray, first: int) -> tuple[str, str]:
    cols = np.nonzero(state[first])[0]
    # the parameter whose alarm run started earliest among those on at the detection instant
    starts = []
    for j in cols:
        k = first
        while k > 0 and state[k - 1, j]:
            k -= 1
        starts.append((k, j))
    name = seg["names"][min(starts)[1]]
    prefix, wheel = name.split("_", 1)
    return wheel, ("gain" if prefix == "rho" else "friction")


def _isolated_residual(seg: dict, first: int, window: int = 10) -> tuple[str, str]:
    r = np.asarray(seg["residual"])[max(0, first - window) : first + 1].mean(axis=0)
    sig = np.asarray(seg["signatures"])[first]  # (2 p, 2)
    norms = np.linalg.norm(sig, axis=1) * (np.linalg.norm(r) + 1e-300)
    cos = np.abs(sig @ r) / np.where(norms > 0, norms, np.inf)
    j = int(np.argmax(cos))
    p = sig.shape[0] // 2
    from ..model import wheel_names

    w = list(wheel_names(p // 2))[j % p]
    return w, ("gain" if j < p else "friction")


def sweep_fdi(
    segments: Sequence[dict],
    thresholds: Sequence[float] = (0.05, 0.1, 0.15, 0.2, 0.3, 0.5),
    dwells: Sequence[float] = (0.5, 1.0, 2.0, 3.0),
    cusum_h: Sequence[float] = (2.0, 5.0, 10.0, 20.0, 50.0, 100.0),
    cusum_drift: Sequence[float] = (0.5, 1.0),
    skip: float = 2.0,
) -> dict:
    """ROC, delay and isolation of both detectors over traces of :func:`fdi_traces` (one scheme)."""
    segs = [s for s in segments if s["status"] == "ok"]
    out: dict = {"n_samples": len(segs), "skip": skip, "estimate": [], "residual": []}
    for kind, detector, settings, keys in (
        ("estimate", _estimate_state, [(c, dwell) for dwell in dwells for c in thresholds], ("threshold", "dwell")),
        ("residual", _cusum, [(h, drift) for drift in cusum_drift for h in cusum_h], ("h", "drift")),
    ):
        for p in roc(segs, detector, settings, skip):
            p["isolation"] = _isolation(segs, detector, p["setting"], skip, kind)
            p[keys[0]], p[keys[1]] = p.pop("setting")
            out[kind].append(p)
    return out


def _isolation(segs, detector, setting, skip, kind: str) -> float | None:
    right = total = 0
    for seg in segs:
        st = detector(seg, setting)
        sc = score(seg["t"], st, seg["t_fault"], skip)
        if not sc["detected"]:
            continue
        total += 1
        st2 = st if st.ndim == 2 else st[:, None]
        guess = (
            _isolated_estimate(seg, st2, sc["first"]) if kind == "estimate" else _isolated_residual(seg, sc["first"])
        )
        right += guess in _truth(seg["faults"])
    return right / total if total else None


# ---------------------------------------------------------------------- execution (edge)
ACTIVE = tuple(name for name, sc in built_in().items() if sc.family == "active")  # the registry's active schemes


@locked("fdi")
def run_fdi(
    base,
    samples: int,
    out,
    seed: int = 0,
    schemes: list[str] | None = None,
    calibration: tuple[float, float] | None = None,
    scheduler: str | None = None,
    workers: int = 2,
    in_process: bool = False,
    show_progress: bool = True,
    force: bool = False,
    sweep: dict | None = None,
) -> dict:
    """Run (or resume) the FDI evaluation: ``samples`` campaign samples per active scheme; results in ``out``.

    Same seeds, Dask path, keys and resumption as the campaign; writes ``traces/<task>.json``,
    ``fdi.json`` (the sweeps per scheme), ``manifest.json`` and ``index.html``.  ``calibration``
    defaults to [2 s, the campaign's earliest fault time).
    """
    from pathlib import Path

    from ..storage.manifest import build_manifest, write_manifest
    from ..storage.store import _jsonable, write_atomic
    from .campaign import CampaignResult, case_content_hash, expected_identity, load_records, run_hash, run_tasks

    if base.campaign is None:
        raise FtcError(f"{base.name}: no [campaign] table: the FDI evaluation draws campaign samples")
    configured = [s for s in ACTIVE if getattr(base.schemes, s) is not None]
    if schemes is not None and configured:  # a name that is no active scheme of the case: the option's fault
        from ..cases import option_schemes

        option_schemes("--schemes", list(schemes), base, among=configured)
    schemes = configured if schemes is None else list(schemes)
    if not schemes or any(s not in configured for s in schemes):
        raise FtcError(f"{base.name}: the FDI evaluation needs active schemes (configured: {configured or 'none'})")
    if calibration is None:
        calibration = (2.0, float(base.campaign.fault_time[0]))
    if not calibration[0] < calibration[1]:
        raise FtcError(f"--calibration: empty fault-free window {list(calibration)} s")
    out = Path(out)
    (out / "traces").mkdir(parents=True, exist_ok=True)
    chash = case_content_hash(base)
    settings = {"schemes": schemes, "seed": int(seed), "calibration": list(calibration)}
    rhash = run_hash("fdi", {"case": chash, **settings})
    expected = expected_identity(chash, rhash)
    records, stale = load_records(out / "traces", expected, force, what="task")
    tasks = {i * len(schemes) + j: (i, s) for i in range(samples) for j, s in enumerate(schemes)}
    todo = [k for k in tasks if k not in records]
    base_json = base.model_dump_json()
    res = CampaignResult(out=out, table=out / "fdi.json", requested=len(tasks))
    failed = res.failed
    run_tasks(
        _fdi_task,
        {k: (base_json, k, tasks[k][0], int(seed), tasks[k][1], tuple(calibration), rhash) for k in todo},
        "fdi",
        expected,
        out / "traces",
        "task",
        8,
        records,
        res,
        show_progress,
        scheduler=scheduler,
        workers=workers,
        in_process=in_process,
    )
    result: dict = {"case": base.name, **settings, "schemes_results": {}}
    for s in schemes:
        segs = [records[k] for k in sorted(records) if k in tasks and tasks[k][1] == s]
        result["schemes_results"][s] = sweep_fdi(segs, **(sweep or {})) | {
            "diverged_or_stopped": sum(r["status"] != "ok" for r in segs)
        }
    write_atomic(out / "fdi.json", json.dumps(_jsonable(result), indent=1).encode())
    write_manifest(
        out / "manifest.json",
        build_manifest(
            "fdi",
            cases={str(base.name): chash},
            fdi=rhash,
            seeds={"campaign": int(seed), "rule": "as campaign: SeedSequence(seed, spawn_key=(sample,)).spawn(2)"},
            settings=settings | {"samples": samples, "scheduler": scheduler, "in_process": in_process},
            workers=res.workers,
            result={"stored": len(records), "rerun_stale": stale, "failed": {str(k): v for k, v in failed.items()}},
        ),
    )
    result["failed"] = failed
    return result


def _fdi_task(base_json, task, index, seed, scheme, calibration, rhash) -> dict:
    rec = fdi_traces(base_json, index, seed, scheme, calibration)
    return rec | {"task": int(task), "campaign": rhash}
