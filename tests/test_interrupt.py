"""Interruption and concurrency (issue 23), through real processes.

* A batch killed with SIGINT or SIGKILL at a random moment (its whole process group,
  workers included, as Ctrl-C or a kill of the job does), then re-run, ends with every
  run complete, metrics identical to an uninterrupted batch (``wall_time``, ``compile_time`` aside) and no
  truncated or temporary file left.
* Two batches started at once on the same ``--out``: the output directory's lock lets
  one run; the other fails at once with a message naming the holder (exit 2).  The
  same for two campaigns on one ``--out`` and for ``report`` while a batch writes.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ftcreport.cases import SCHEME_NAMES, load_case
from ftcreport.evaluation.families import FAMILIES
from ftcreport.storage.store import check_run

CASES = Path(__file__).resolve().parents[1] / "cases"
pytestmark = pytest.mark.slow
CLI = [sys.executable, "-m", "ftcreport.cli"]


@pytest.fixture(scope="module")
def small_cases(tmp_path_factory):
    """Two two-link cases, three schemes each, 4 s long: a six-run batch."""
    d = tmp_path_factory.mktemp("cases")
    out = []
    for name in ("two_link_uncompensable", "two_link_intermittent"):
        data = tomllib.loads((CASES / f"{name}.toml").read_text())
        data.pop("thresholds", None)
        p = d / f"{name}.toml"
        p.write_text(tomli_w.dumps(data))
        out.append(str(p))
    return out


def _batch(cases, out, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        [*CLI, "batch", *cases, "--out", str(out), "--duration", "4", "--jobs", "2", "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: signals reach the workers too
        **kw,
    )


@pytest.fixture(scope="module")
def reference(small_cases, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    p = _batch(small_cases, out)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 0, err
    return out


def _snapshot(out: Path) -> dict:
    """Every run's metrics (wall time aside) and time series; asserts nothing is truncated."""
    snap = {}
    for m in sorted(out.glob("*/*/metrics.json")):
        d = m.parent
        metrics = json.loads(m.read_text())
        metrics.pop("wall_time", None)
        metrics.pop("compile_time", None)  # times, not results
        assert check_run(out, d.parent.name, d.name).sound, d  # its record matches its files
        with np.load(d / "timeseries.npz") as z:
            series = {k: z[k].copy() for k in z.files}
        snap[f"{d.parent.name}/{d.name}"] = (metrics, series)
    for page in [out / "index.html", *out.glob("*/index.html")]:
        assert page.read_text().rstrip().endswith("</html>"), page
    leftovers = [p for p in out.rglob("*") if p.name.endswith(".partial")]
    assert not leftovers, leftovers
    return snap


def _assert_same(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b) and len(a) == 2 * len(FAMILIES)  # two cases, every family (issue 21)
    for k in a:
        assert a[k][0] == b[k][0], k  # every metric identical (the engine is deterministic)
        assert sorted(a[k][1]) == sorted(b[k][1]), k
        for s in a[k][1]:
            np.testing.assert_array_equal(a[k][1][s], b[k][1][s], err_msg=f"{k}: {s}")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_killed_batch_resumes_to_identical_results(small_cases, reference, tmp_path, sig):
    out = tmp_path / "o"
    rng = random.Random()
    when = rng.uniform(2.0, 12.0)  # the reference batch takes 10-25 s on the CI machine
    p = _batch(small_cases, out)
    time.sleep(when)
    if p.poll() is None:
        os.killpg(p.pid, sig)
    _, err = p.communicate(timeout=120)
    print(f"{signal.Signals(sig).name} at {when:.2f} s: exit {p.returncode}")
    assert "Traceback" not in err, err
    if sig == signal.SIGINT and p.returncode != 0:
        assert p.returncode == 130 and "interrupted" in err, (p.returncode, err)
    again = _batch(small_cases, out)
    _, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    _assert_same(_snapshot(out), _snapshot(reference))


def test_two_batches_at_once_one_runs_one_is_refused(small_cases, reference, tmp_path):
    out = tmp_path / "o"
    a, b = _batch(small_cases, out), _batch(small_cases, out)
    ra, rb = a.communicate(timeout=600), b.communicate(timeout=600)
    codes = sorted([a.returncode, b.returncode])
    assert codes == [0, 2], (codes, ra[1], rb[1])
    refused = ra[1] if a.returncode == 2 else rb[1]
    assert "in use by ftcreport batch (pid" in refused and "Traceback" not in refused
    assert refused.strip().count("\n") == 0
    _assert_same(_snapshot(out), _snapshot(reference))


def test_report_while_a_batch_writes_is_refused(small_cases, tmp_path):
    out = tmp_path / "o"
    p = _batch(small_cases, out)
    lock = out / ".ftcreport.lock"
    t0 = time.time()
    while not (lock.exists() and lock.read_text()) and time.time() - t0 < 60:
        time.sleep(0.05)
    rep = subprocess.run([*CLI, "report", "--out", str(out)], capture_output=True, text=True, timeout=120)
    p.communicate(timeout=600)
    assert p.returncode == 0
    assert rep.returncode == 2 and "in use by ftcreport batch" in rep.stderr and "Traceback" not in rep.stderr
    after = subprocess.run([*CLI, "report", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert after.returncode == 0, after.stderr


def test_two_campaigns_at_once_one_runs_one_is_refused(tmp_path):
    out = tmp_path / "camp"
    args = [*CLI, "campaign", str(CASES / "two_link_campaign.toml"), "-n", "3", "--in-process", "-q"]
    a = subprocess.Popen([*args, "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    b = subprocess.Popen([*args, "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ra, rb = a.communicate(timeout=600), b.communicate(timeout=600)
    codes = sorted([a.returncode, b.returncode])
    assert codes == [0, 2], (codes, ra, rb)
    refused = ra[1] if a.returncode == 2 else rb[1]
    assert "in use by ftcreport campaign (pid" in refused
    rows = (out / "results.csv").read_text().strip().splitlines()
    case = load_case(CASES / "two_link_campaign.toml")
    schemes = [s for s in SCHEME_NAMES if getattr(case.schemes, s) is not None]  # every family (issue 21)
    assert len(rows) == 1 + 3 * len(schemes)  # header + every sample x scheme, once


# ------------------------------------------------------------------ issue 34, break 4: processes end with their command
def test_stop_signals_raise_and_a_hangup_ignored_at_start_stays_ignored():
    """SIGTERM raises Interrupted (exit 143); a SIGHUP the process was started ignoring (nohup) stays ignored."""
    from ftcreport.infra.lifetime import Interrupted, exit_code, handle_stop_signals

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with pytest.raises(Interrupted) as caught, handle_stop_signals():
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.2)  # not raised: still ignored
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        assert caught.value.signum == signal.SIGTERM and exit_code(caught.value) == 143
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


@pytest.mark.parametrize("how", ["pdeathsig", "polling"])
def test_a_process_tied_to_its_parent_ends_when_the_parent_is_killed(how, tmp_path):
    """die_with_parent: Linux's parent-death signal, and the portable fallback (polling the parent's pid)."""
    patch = "L._set_pdeathsig = lambda: False; " if how == "polling" else ""
    tied = tmp_path / "tied"
    grandchild = (
        f"import os, pathlib, time, ftcreport.infra.lifetime as L; {patch}L.die_with_parent(os.getppid()); "
        f"pathlib.Path({str(tied)!r}).touch(); time.sleep(60)"
    )
    parent = (
        "import subprocess, sys, time\n"
        f"p = subprocess.Popen([sys.executable, '-c', {grandchild!r}])\n"
        "print(p.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True)
    pid = int(proc.stdout.readline())
    t0 = time.time()
    while not tied.exists() and time.time() - t0 < 60:  # the grandchild has tied itself to its parent
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    t0 = time.time()
    while time.time() - t0 < 5.0:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            break
        if state in ("Z", "X"):
            break
        time.sleep(0.05)
    else:
        os.kill(pid, signal.SIGKILL)
        pytest.fail(f"the process tied to its parent ({how}) still runs 5 s after the parent was killed")
    print(f"{how}: ended {time.time() - t0:.2f} s after its parent")


def test_an_interrupt_wrapped_by_compiled_code_is_an_interrupt():
    """numba's dispatcher returns "a result with an exception set" when a signal handler raised during the
    call: Python raises SystemError from the interrupt; it is the interrupt (not the task's failure)."""
    from ftcreport.infra.lifetime import Interrupted, interrupt_of

    stop = Interrupted(signal.SIGHUP)
    try:
        try:
            raise stop
        except KeyboardInterrupt as exc:
            raise SystemError("CPUDispatcher(<function run_steps>) returned a result with an exception set") from exc
    except SystemError as wrapped:
        assert interrupt_of(wrapped) is stop
    assert interrupt_of(ValueError("x")) is None


def test_a_stop_signal_inside_a_callback_from_c_is_sent_again_not_raised(monkeypatch):
    """CI, round 3: SIGTERM arrived while LLVM was inside llvmlite's object-cache callback (a cached kernel
    loading); the handler raised there, Python printed "Exception ignored on calling ctypes callback
    function" and dropped it, LLVM got no buffer and the process died with -11.  In a frame of llvmlite
    (or of numba's unpickling from compiled code) the handler sends the signal again 50 ms later, and
    raises once the callback has returned."""
    import llvmlite.binding

    from ftcreport import lifetime

    sent = []
    monkeypatch.setattr(lifetime.os, "kill", lambda pid, sig: sent.append((pid, sig)))
    where = str(Path(llvmlite.binding.__file__).parent / "executionengine.py")
    scope = {"handler": lifetime._on_stop_signal, "sys": sys, "signum": signal.SIGTERM}
    exec(compile("def _raw_object_cache_getbuffer():\n    handler(signum, sys._getframe())\n", where, "exec"), scope)
    scope["_raw_object_cache_getbuffer"]()  # as the callback: no exception
    deadline = time.monotonic() + 5.0
    while not sent and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sent == [(os.getpid(), signal.SIGTERM)]
    with pytest.raises(lifetime.Interrupted):  # anywhere else: raised at once
        lifetime._on_stop_signal(signal.SIGTERM, sys._getframe())


def test_a_stopped_pool_has_ended_its_manager_thread():
    """CI, round 3: a batch stopped by SIGHUP printed its line, then "Exception ignored ... OSError: [Errno 9]
    Bad file descriptor": the pool, shut down without waiting, was still closing its wake-up pipe in its
    manager thread when the interpreter's exit wrote to it.  Once stop_pool returns, the manager thread is
    gone (and the worker with it), so nothing is left to race with the exit."""
    import multiprocessing as mp
    import threading
    from concurrent.futures import ProcessPoolExecutor

    from ftcreport.infra.lifetime import stop_pool

    before = set(threading.enumerate())
    pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
    running = pool.submit(time.sleep, 60)
    waiting = pool.submit(time.sleep, 60)
    deadline = time.monotonic() + 60
    while not running.running() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert running.running()
    workers = list(pool._processes.values())
    t0 = time.monotonic()
    stop_pool(pool)
    assert time.monotonic() - t0 < 5.0  # the workers were terminated, not waited out
    assert set(threading.enumerate()) - before == set()  # the manager thread (and its feeder) ended
    assert not any(w.is_alive() for w in workers)
    assert waiting.cancelled() or isinstance(waiting.exception(timeout=0), Exception)


def _alive(session: int) -> list[str]:
    """The processes of a session (the command started with start_new_session) still running (zombies aside)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if os.getsid(int(d.name)) != session:
                continue
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")[:120]
        except (OSError, IndexError):
            continue
        if state not in ("Z", "X"):
            out.append(f"{d.name} {state} {cmd}")
    return out


def _files(out: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``out``: (mtime in ns, size)."""
    return {str(p): (p.stat().st_mtime_ns, p.stat().st_size) for p in out.rglob("*") if p.is_file()}


def _wait_for(cond, p: subprocess.Popen, timeout: float = 300) -> None:
    t0 = time.time()
    while not cond():
        assert p.poll() is None, ("the command ended before the signal", p.communicate())
        assert time.time() - t0 < timeout, "timed out"
        time.sleep(0.02)


def _complete_runs(out: Path) -> int:
    return sum(1 for k in out.glob("*/*/record.json") if k.read_text().strip())


def _assert_ended_cleanly(p: subprocess.Popen, out: Path, sig: int, err: str, noun: str | None = "run") -> int:
    """Exit 128 + sig, one line saying how many finished ``noun``s are stored (None: a command that stores
    none), every process of the command gone within 5 s, no partial file, nothing changing, the lock free
    with no holder text.  The count."""
    import fcntl
    import re

    assert p.returncode == 128 + sig, (p.returncode, err)
    # the pages' progress line (piped: 'rendering N case page(s) ...', said before the work) is not part of it
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("rendering ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    how = "interrupted" if sig == signal.SIGINT else f"interrupted by {signal.Signals(sig).name}"
    stored = (
        rf"; (\d+) finished {noun}s? (?:is|are) stored, re-run the same command to resume"
        rf"| before any {noun} finished; nothing was stored"
    )
    m = re.fullmatch(rf"ftcreport: error: {how}(?:{stored})" if noun else rf"ftcreport: error: {how}()", lines[0])
    assert m, lines[0]
    t0 = time.time()
    while _alive(p.pid) and time.time() - t0 < 5.0:
        time.sleep(0.1)
    assert not _alive(p.pid), _alive(p.pid)
    before = _files(out)
    time.sleep(2.0)
    assert _files(out) == before  # nobody writes after the command ended
    assert not [f for f in before if f.endswith(".partial")]
    lock = out / ".ftcreport.lock"
    assert lock.read_text() == ""
    with open(lock, "a") as fh:  # free: this process gets it at once
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    return int(m.group(1) or 0)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_ends_the_batch_and_its_workers(small_cases, reference, tmp_path, sig):
    """The signal to the batch process alone (``kill PID``): before, SIGTERM ended it with no message and
    its two workers, re-parented to PID 1, went on writing results into --out after its lock was released."""
    out = tmp_path / "o"
    p = _batch(small_cases, out)
    _wait_for(lambda: _complete_runs(out) >= 1, p)  # the workers are running: one run is stored
    os.kill(p.pid, sig)
    _, err = p.communicate(timeout=120)
    stored = _assert_ended_cleanly(p, out, sig, err)
    assert stored == _complete_runs(out) >= 1  # the message counts what is on disk, complete


def test_a_sigkilled_batch_leaves_no_worker_and_no_write(small_cases, reference, tmp_path):
    """SIGKILL of the batch process alone: its workers end at once (parent-death signal) and nothing under
    --out changes after it is gone; the next batch completes the results."""
    out = tmp_path / "o"
    p = _batch(small_cases, out)
    _wait_for(lambda: _complete_runs(out) >= 1, p)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=60)
    gone = _files(out)
    t0 = time.time()
    while _alive(p.pid) and time.time() - t0 < 5.0:
        time.sleep(0.1)
    assert not _alive(p.pid), _alive(p.pid)
    time.sleep(2.0)
    assert _files(out) == gone
    again = _batch(small_cases, out)
    _, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    _assert_same(_snapshot(out), _snapshot(reference))


def _short_campaign(d: Path) -> Path:
    data = tomllib.loads((CASES / "two_link_campaign.toml").read_text())
    data["simulation"]["duration"] = 8.0
    data["campaign"]["fault_time"] = [2.0, 5.0]
    p = d / "camp.toml"
    p.write_text(tomli_w.dumps(data))
    return p


def _campaign_with_a_sample(tmp_path: Path, out: Path, schemes: str) -> subprocess.Popen:
    """A 40-sample campaign of ``schemes`` on its own LocalCluster (2 workers, its own session), once it has
    stored a sample (its workers are up)."""
    args = [*CLI, "campaign", str(_short_campaign(tmp_path)), "-n", "40", "--schemes", schemes, "-q"]
    p = subprocess.Popen(
        [*args, "--workers", "2", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    _wait_for(lambda: any((out / "samples").glob("*.json")), p)
    return p


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_stop_signal_ends_a_campaign_and_its_dask_workers(tmp_path, sig):
    """A campaign on its own LocalCluster (2 worker processes): SIGTERM stops it cleanly (before: no message,
    exit -15, the lock's holder text left); SIGKILL of the client alone ends the workers too."""
    out = tmp_path / "c"
    p = _campaign_with_a_sample(tmp_path, out, "nominal,oracle")
    os.kill(p.pid, sig)
    _, err = p.communicate(timeout=120)
    if sig == signal.SIGKILL:
        t0 = time.time()
        while _alive(p.pid) and time.time() - t0 < 5.0:
            time.sleep(0.1)
        assert not _alive(p.pid), _alive(p.pid)
        return
    stored = _assert_ended_cleanly(p, out, sig, err, noun="sample")
    assert stored == len(list((out / "samples").glob("*.json"))) >= 1


@pytest.mark.parametrize(("command", "sig"), [("coverage", signal.SIGHUP), ("fdi", signal.SIGTERM)])
def test_a_stop_signal_ends_coverage_and_fdi(tmp_path, command, sig):
    """In this process (--in-process): before, SIGHUP and SIGTERM ended them with no message and the
    lock's holder text left; a signal that came back wrapped by the compiled engine was stored as a
    failed item and the command went on."""
    data = tomllib.loads((CASES / "two_link_campaign.toml").read_text())
    data["schemes"]["active"] = {"k_v": 5.0, "Theta": 1.6, "p_max": 1e10}
    data["simulation"]["duration"] = 12.0
    data["campaign"] |= {"fault_time": [5.0, 8.0], "sigma": [0.3, 0.6], "friction_probability": 0.0}
    case = tmp_path / "c.toml"
    case.write_text(tomli_w.dumps(data))
    out = tmp_path / "o"
    extra = ["--schemes", "nominal"] if command == "coverage" else ["-n", "20"]
    p = subprocess.Popen(
        [*CLI, command, str(case), *extra, "--in-process", "-q", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    folder = out / ("items" if command == "coverage" else "traces")
    _wait_for(lambda: any(folder.glob("*.json")), p)
    os.kill(p.pid, sig)
    _, err = p.communicate(timeout=120)
    noun = "item" if command == "coverage" else "task"
    stored = _assert_ended_cleanly(p, out, sig, err, noun=noun)
    assert stored == len(list(folder.glob("*.json"))) >= 1
    assert not (out / "failed.json").exists()  # the interrupt is no task's failure


def test_a_stop_signal_ends_report(reference, tmp_path):
    import shutil

    out = tmp_path / "o"
    shutil.copytree(reference, out)
    p = subprocess.Popen(
        [*CLI, "report", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    lock = out / ".ftcreport.lock"
    _wait_for(lambda: "report" in lock.read_text(), p)
    time.sleep(0.5)  # rendering the first page
    os.kill(p.pid, signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    _assert_ended_cleanly(p, out, signal.SIGTERM, err, noun=None)
    assert not (out / "index.html").exists() or (out / "index.html").read_text().rstrip().endswith("</html>")


def test_a_ctrl_c_to_the_whole_process_group_prints_no_worker_traceback(tmp_path):
    """A terminal sends Ctrl-C to its foreground process group: the command and its Dask workers.  Each worker
    answered it with a KeyboardInterrupt traceback (34-111 lines of stderr in 4 of 6 trials, session 13; the
    test above signals the command alone).  Once the workers are up (a sample stored), the command's one line
    is all: the workers ignore SIGINT, and the command closes them."""
    out = tmp_path / "c"
    p = _campaign_with_a_sample(tmp_path, out, "nominal")
    os.killpg(p.pid, signal.SIGINT)  # the session's process group: as a terminal's Ctrl-C
    _, err = p.communicate(timeout=120)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert p.returncode == 130, (p.returncode, err)
    _assert_ended_cleanly(p, out, signal.SIGINT, err, noun="sample")


def test_a_campaign_interrupted_while_its_cluster_starts_prints_one_line(tmp_path):
    """SIGINT while the LocalCluster starts, checks versions or warms its workers up (before: ~30 lines of
    traceback, "Future exception was never retrieved ... CommClosedError" or an atexit
    "AssertionError: Status.init", before the one line).  Three moments after campaign.json appears."""
    case = _short_campaign(tmp_path)
    for k, delay in enumerate((0.8, 1.8, 3.0)):
        out = tmp_path / f"c{k}"
        p = subprocess.Popen(
            [*CLI, "campaign", str(case), "-n", "400", "--schemes", "nominal", "-q", "--out", str(out)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        _wait_for(lambda out=out: (out / "campaign.json").exists(), p, timeout=60)
        time.sleep(delay)
        os.kill(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=60)
        assert "Traceback" not in err and "Future exception" not in err, (delay, err)
        assert p.returncode == 130, (delay, p.returncode, err)
        _assert_ended_cleanly(p, out, signal.SIGINT, err, noun="sample")
