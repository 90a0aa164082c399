"""Issue 34, breaks 5, 6 and 8: input files that are not files, symbolic links in --out, writers without a lock.

Each test reproduces a break of the issue through the CLI (it failed before the fix) and asserts the
exit code, the message and the files left:

* 5: a case file, base case or scheme file that is a FIFO, a device, a directory (or a symbolic link
  to one), or larger than the bound, is refused at once with exit 2 and a message naming it; a batch
  goes on past it.  (A FIFO hung forever; /dev/zero filled the memory: the commands run here in a
  process limited to 2 GB of address space, under a timeout.)
* 6: a lock file that is a symbolic link (or a hard link) is refused and its target left untouched;
  a case folder inside --out that is a symbolic link is refused, never followed outside.
* 8: coverage, fdi and export take the output directory's lock; a coverage map never overwrites a
  batch's index.html and manifest.json, and two coverages at once do not both run every item.
"""

from __future__ import annotations

import json
import os
import resource
import socket
import subprocess
import sys
import textwrap
import time
import tomllib
from pathlib import Path

import pytest
import tomli_w

CASES = Path(__file__).resolve().parents[1] / "cases"
CLI = [sys.executable, "-m", "ftcreport.cli"]
MEMORY_LIMIT = 2 << 30  # bytes of address space a command under test may take (a run needs about 1.2 GB)


def _limited() -> None:  # pragma: no cover - runs in the child
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def _cli(*args: str, timeout: float = 120, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """The command in its own process, memory-limited and under a timeout (a hang fails the test)."""
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, preexec_fn=_limited, cwd=cwd)


def _one_line(res: subprocess.CompletedProcess, code: int, *needles: str) -> str:
    """Exit ``code`` and exactly one error line on stderr naming every needle."""
    lines = [ln for ln in res.stderr.splitlines() if ln.strip() and not ln.startswith("warning: ")]
    assert res.returncode == code, (res.returncode, res.stdout, res.stderr)
    assert "Traceback" not in res.stderr and len(lines) == 1, res.stderr
    assert lines[0].startswith("ftcreport: error: "), lines[0]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def _case(d: Path, name: str = "short", fname: str | None = None, **top) -> Path:
    """two_link_intermittent shortened to 0.5 s (one fault), nominal scheme only, without thresholds or claims."""
    data = tomllib.loads((CASES / "two_link_intermittent.toml").read_text())
    data["name"] = name
    data["schemes"] = {"nominal": data["schemes"]["nominal"]}
    data["simulation"]["duration"] = 0.5
    data["faults"] = [{"time": 0.25, "wheel": "1l"}]  # motor 1l lost half-way
    for k in ("thresholds", "claims", "expected_status_of"):
        data.pop(k, None)
    for k, v in top.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    p = d / (fname or f"{name}.toml")
    p.write_text(tomli_w.dumps(data))
    return p


def _special(d: Path, kind: str) -> Path:
    """A path named ``x.toml`` in ``d`` that is not a regular file of a sane size."""
    p = d / "x.toml"
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "dev_zero":
        p.symlink_to("/dev/zero")
    elif kind == "directory":
        p.mkdir()
    elif kind == "link_to_fifo":
        os.mkfifo(d / "pipe")
        p.symlink_to(d / "pipe")
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(p))
        s.close()
    elif kind == "oversize":
        p.write_bytes(b"# padding\n" * 200_000)  # 2 MB of valid TOML: over the 1 MiB bound
    return p


WHAT = {
    "fifo": "not a regular file (a FIFO)",
    "dev_zero": "not a regular file (a character device, a symbolic link to /dev/zero)",
    "directory": "not a regular file (a directory)",
    "link_to_fifo": "not a regular file (a FIFO, a symbolic link to",
    "socket": "not a regular file (a socket)",
    "oversize": "too large (2000000 bytes; a case file may have 1 MiB",
}


# ------------------------------------------------------------------ break 5: inputs that are files
@pytest.mark.parametrize("kind", sorted(WHAT))
def test_a_case_file_that_is_no_regular_file_is_refused_at_once(tmp_path, kind):
    p = _special(tmp_path, kind)
    t0 = time.perf_counter()
    res = _cli("run", str(p), "--out", str(tmp_path / "o"), timeout=60)
    _one_line(res, 2, f"{p}: ", WHAT[kind])
    assert time.perf_counter() - t0 < 30  # at once: nothing read (the FIFO hung, /dev/zero read until out of memory)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("role", ["base_case", "plugins"])
def test_a_base_case_or_scheme_file_that_is_a_device_or_fifo_is_refused(tmp_path, role):
    if role == "base_case":
        p = tmp_path / "over.toml"
        p.write_text('base_case = "/dev/zero"\nname = "over"\n')
        needles = (f"{p}: base_case: '/dev/zero': /dev/zero: not a regular file (a character device)",)
    else:
        os.mkfifo(tmp_path / "law.py")
        p = _case(tmp_path, plugins=["law.py"])
        needles = (f"{p}: plugins[0]: ", "law.py: not a regular file (a FIFO)", "a scheme file must be a regular file")
    _one_line(_cli("cases", "validate", str(p), timeout=60), 2, *needles)


def test_a_batch_goes_on_past_files_that_are_not_files(tmp_path):
    d = tmp_path / "cases"
    d.mkdir()
    good = _case(d, "good")
    fifo = _special(d, "fifo")  # x.toml, found by the directory's *.toml
    (d / "sub.toml").mkdir()
    (d / "zero.toml").symlink_to("/dev/zero")
    res = _cli("batch", str(d), "--out", str(tmp_path / "o"), "--jobs", "1", "-q", timeout=400)
    assert res.returncode == 2 and "Traceback" not in res.stderr, (res.returncode, res.stderr)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error: ")]
    for path, what in ((fifo, "FIFO"), (d / "sub.toml", "directory"), (d / "zero.toml", "character device")):
        assert sum(f"{path}: not a regular file (a {what}" in ln for ln in errors) == 1, (path, errors)
    assert res.stdout.startswith("1 case(s): ") and "3 case file(s) rejected" in res.stdout, res.stdout
    assert (tmp_path / "o" / "good" / "nominal" / "metrics.json").is_file() and good.is_file()


# ------------------------------------------------------------------ break 6: symbolic links
@pytest.mark.parametrize("link", ["symbolic", "hard"])
def test_a_linked_lock_file_is_refused_and_its_target_untouched(tmp_path, link):
    out = tmp_path / "o"
    out.mkdir()
    victim = tmp_path / "precious.txt"
    victim.write_text("precious data\n")
    if link == "symbolic":
        (out / ".ftcreport.lock").symlink_to(victim)
    else:
        os.link(victim, out / ".ftcreport.lock")
    res = _cli("run", str(_case(tmp_path)), "--out", str(out), "--no-report", "-q")
    why = "is a symbolic link" if link == "symbolic" else "has other hard links"
    _one_line(res, 2, str(out / ".ftcreport.lock"), why, "remove it")
    assert victim.read_text() == "precious data\n"  # it was blanked at exit
    assert sorted(p.name for p in out.iterdir()) == [".ftcreport.lock"]  # nothing written


def test_a_symlinked_case_folder_inside_out_is_refused_not_followed(tmp_path):
    out, elsewhere = tmp_path / "o", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "short").symlink_to(elsewhere)
    res = _cli("run", str(_case(tmp_path)), "--out", str(out), "--no-report", "-q")
    _one_line(res, 2, f"{out / 'short'}: is a symbolic link (to {elsewhere})", "writes results only inside --out")
    assert list(elsewhere.iterdir()) == []
    # a batch refuses that case and goes on with the others
    other = _case(tmp_path, "other")
    res = _cli("batch", str(_case(tmp_path)), str(other), "--out", str(out), "--jobs", "1", "-q", timeout=400)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert f"{out / 'short'}: is a symbolic link" in res.stderr
    assert list(elsewhere.iterdir()) == [] and (out / "other" / "nominal" / "metrics.json").is_file()


def test_an_out_that_is_itself_a_link_is_followed_and_the_readme_says_so(tmp_path):
    """--out given as a symbolic link to a directory (reports -> a larger disk) is a use kept on purpose:
    the link is the user's own choice of place, and the results stay inside the directory it names.
    What is refused is a link *below* --out (test above); the README's exit-2 row says which."""
    target = tmp_path / "disk" / "reports"
    target.mkdir(parents=True)
    link = tmp_path / "reports"
    link.symlink_to(target)
    res = _cli("run", str(_case(tmp_path)), "--out", str(link), "--no-report", "-q", timeout=400)
    assert res.returncode == 0, res.stderr
    assert (target / "short" / "nominal" / "record.json").is_file() and link.is_symlink()
    readme = " ".join((CASES.parent / "README.md").read_text().split())
    row = readme[readme.index("| 2 | bad input") :].split(" |", 2)[1]
    assert "a case folder or lock file below it that is a symbolic link" in row, row
    assert "`--out` itself may be a symbolic link to a directory" in row, row


# ------------------------------------------------------------------ break 8: every writer locks
def _hold_lock(out: Path, command: str = "batch") -> subprocess.Popen:
    code = textwrap.dedent(
        f"""
        import sys, time
        from ftcreport.storage.store import output_lock
        with output_lock({str(out)!r}, {command!r}):
            print("held", flush=True)
            time.sleep(120)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def _small_coverage(case: Path, kinds: str = "loss") -> list[str]:
    """Wheel losses at one onset, nominal only, in this process: a few seconds."""
    return ["coverage", str(case), "--kinds", kinds, "--times", "0.2", "--schemes", "nominal", "--in-process", "-q"]


@pytest.mark.parametrize("command", ["export", "coverage", "fdi"])
def test_export_coverage_and_fdi_take_the_lock(tmp_path, command):
    out = tmp_path / "o"
    case = _case(tmp_path)
    if command == "export":  # results to export (before: exported while a batch held the directory)
        assert _cli("run", str(case), "--out", str(out), "--no-report", "-q", timeout=400).returncode == 0
    holder = _hold_lock(out, {"export": "batch"}.get(command, command))
    try:
        args = {
            "export": ["export", "--out", str(out)],
            "coverage": [*_small_coverage(case), "--out", str(out)],
            "fdi": ["fdi", str(CASES / "two_link_campaign.toml"), "-n", "1", "--in-process", "-q", "--out", str(out)],
        }[command]
        _one_line(_cli(*args, timeout=300), 2, f"{out}: --out: in use by ftcreport")
    finally:
        holder.kill()
        holder.wait()


def test_coverage_never_overwrites_a_batch_directory(tmp_path):
    out = tmp_path / "o"
    case = _case(tmp_path)
    assert _cli("run", str(case), "--out", str(out), "-q", timeout=400).returncode == 0
    before = {p.name: p.read_bytes() for p in (out / "index.html", out / "short" / "manifest.json")}
    res = _cli(*_small_coverage(case), "--out", str(out), timeout=400)
    _one_line(res, 2, f"{out}: --out: holds the results of another kind of command", "choose another --out")
    assert {p.name: p.read_bytes() for p in (out / "index.html", out / "short" / "manifest.json")} == before
    assert not (out / "items").exists() and not (out / "coverage.csv").exists()
    # and a batch never writes into a coverage map's directory
    cov = tmp_path / "cov"
    assert _cli(*_small_coverage(case), "--out", str(cov), timeout=400).returncode == 0
    page = (cov / "index.html").read_bytes()
    res = _cli("batch", str(case), "--out", str(cov), "-q", timeout=400)
    _one_line(res, 2, f"{cov}: --out: holds the results of another kind of command (a coverage map)")
    assert (cov / "index.html").read_bytes() == page and not (cov / "short").exists()


def test_two_coverages_at_once_one_runs_one_is_refused(tmp_path):
    out = tmp_path / "o"
    args = [*CLI, *_small_coverage(_case(tmp_path), "loss,friction"), "--out", str(out)]
    a, b = (subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2))
    ra, rb = a.communicate(timeout=300), b.communicate(timeout=300)
    assert sorted([a.returncode, b.returncode]) == [0, 2], (ra, rb)
    refused = ra[1] if a.returncode == 2 else rb[1]
    assert refused.count("\n") == 1 and f"{out}: --out: in use by ftcreport coverage (pid" in refused, refused
    items = [json.loads(p.read_text()) for p in sorted((out / "items").glob("*.json"))]
    assert sorted(r["item"] for r in items) == list(range(8))  # 4 wheels x 2 kinds, each run once


def _files(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_export_never_overwrites_another_commands_directory(tmp_path):
    """Audit of issue 34: ``export --out A --dest B`` with B another batch's output replaced B's
    metrics.parquet with A's rows (exit 0); now refused, exit 2, B untouched, and a batch never
    writes into an export's directory either."""
    a, b = tmp_path / "a", tmp_path / "b"
    for out, name in ((a, "short"), (b, "other")):
        res = _cli("batch", str(_case(tmp_path, name)), "--out", str(out), "--jobs", "1", "-q", timeout=400)
        assert res.returncode == 0, res.stderr
    before = _files(b)
    res = _cli("export", "--out", str(a), "--dest", str(b))
    _one_line(res, 2, f"{b}: --dest: holds the results of another kind of command (case results of batch/run)")
    assert _files(b) == before
    other = tmp_path / "campaign-like"  # a directory of another family (found by its files)
    other.mkdir()
    (other / "coverage.json").write_text("{}")
    _one_line(_cli("export", "--out", str(a), "--dest", str(other)), 2, f"{other}: --dest: ", "a coverage map")
    dest = tmp_path / "exported"
    for _ in range(2):  # a fresh destination, then the same export again: both fine
        res = _cli("export", "--out", str(a), "--dest", str(dest))
        assert res.returncode == 0 and (dest / "metrics.parquet").is_file(), res.stderr
    kept = _files(dest)
    res = _cli("batch", str(_case(tmp_path, "short")), "--out", str(dest), "-q", timeout=400)
    _one_line(res, 2, f"{dest}: --out: holds the results of another kind of command (an export")
    assert _files(dest) == kept
    assert _cli("export", "--out", str(a)).returncode == 0  # beside the results: still the batch's own


def test_python_dash_m_ftcreport_is_the_command_line():
    """``python -m ftcreport`` runs the command line, as ``python -m ftcreport.cli`` and the ``ftcreport`` script
    do (session 13: it printed "No module named ftcreport.__main__", a dead end for a user without the script on
    PATH)."""
    r = subprocess.run([sys.executable, "-m", "ftcreport", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "batch" in r.stdout and "check" in r.stdout
