r"""The Dask edge shared by campaigns and coverage maps: task keys, version check, warm-up, execution.

A task's key names what it computes, so that two clients on one scheduler can
never receive each other's results (issue 22).  The Dask scheduler identifies a
task by its key only: a second client submitting *another* function under a
key that is already held receives the first client's result.  The old key
``sample-{seed}-{i}`` was the same for two campaigns on the default seed; the
key is ``ftcreport-{kind}-{run hash}-{index}`` where the run hash covers
the base case content, the schemes, the settings and the package version
(:func:`ftcreport.studies.campaign.run_hash`, :func:`ftcreport.studies.campaign.task_key`).

Before submitting, :func:`check_versions` compares the versions the workers
report through Dask's own version report (``Client.get_versions``, which also
warns on Dask's own mismatches) with the client's, for the package and every
dependency that can change a simulated number, and the package's source digest
each worker computes (``Client.run``: the same version can be an edited checkout); a
mismatch is refused.  A worker plugin (:class:`WarmUp`) loads the compiled kernels once per worker
(``ftcreport.sim.warm_up``), so no sample pays the numba load.

:func:`execute` runs ``func(*args)`` for every index, in this process or on a
``LocalCluster`` / existing scheduler through the same ``client.submit`` path,
and hands each result to ``store`` as it finishes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import sys
import threading
from collections.abc import Callable, Mapping
from typing import Any

from distributed import WorkerPlugin

from ..errors import FtcError
from ..infra.lifetime import deferred, interrupt_of, shielded
from ..infra.limits import worker_count
from ..storage.manifest import NUMERIC_DEPENDENCIES

__all__ = ["CHECKED_PACKAGES", "WarmUp", "check_versions", "execute", "worker_code"]

#: seconds a LocalCluster is given to close its workers (then its processes end with this one:
#: each worker process exits when the pipe to its parent closes, distributed.process)
CLOSE_TIMEOUT_S = 20

#: Packages whose version must be the same on the client and every worker (besides Python).
CHECKED_PACKAGES: tuple[str, ...] = ("ftcreport", "dask", "distributed", "cloudpickle", *NUMERIC_DEPENDENCIES)


class WarmUp(WorkerPlugin):
    """Loads (or compiles once) the numba kernels on each worker when it joins; off the event loop.

    ``quiet`` (the workers of this command's own LocalCluster): Dask's log on the worker is not
    printed.  A stopped command's cancelled tasks each logged a warning, and a worker still busy
    when the scheduler closed an error with a traceback; a task's own error comes back to the
    command with its result (:func:`execute`'s ``fail``), and a lost worker is logged by its nanny,
    which runs in the command's process.  Nor do they answer a Ctrl-C: the terminal sends it to its
    whole process group, workers included, and each printed a KeyboardInterrupt traceback (34-111 lines in
    4 of 6 trials, session 13); the command's one line says it, and the command closes its workers.  A
    worker ignores SIGINT from its plugin's setup on; one still starting (importing) then can answer it.
    """

    name = "ftcreport-warm-up"

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet

    async def setup(self, worker) -> None:
        from ..sim import warm_up

        if self.quiet:
            logging.getLogger("distributed").setLevel(logging.CRITICAL)
            if threading.current_thread() is threading.main_thread():  # the worker process's own loop
                signal.signal(signal.SIGINT, signal.SIG_IGN)
        loop = asyncio.get_running_loop()
        self.seconds = await loop.run_in_executor(None, warm_up)


def check_versions(client) -> dict[str, dict[str, str | None]]:
    """Refuse workers whose Python, package or numeric-dependency versions, or package sources, differ from the
    client's.

    Uses Dask's version report (``Client.get_versions(check=True, packages=...)``: it warns itself
    on Dask's own mismatches), then each worker's source digest (``Client.run`` of :func:`worker_code`);
    returns ``{worker address: {package: version, "code": digest}}``.
    """
    got = client.get_versions(check=True, packages=list(CHECKED_PACKAGES))
    mine = got["client"]["packages"]
    keys = ("python", *CHECKED_PACKAGES)
    out: dict[str, dict[str, str | None]] = {}
    for addr, info in sorted(got["workers"].items()):
        pk = (info or {}).get("packages", {}) if isinstance(info, dict) else {}
        out[addr] = {k: pk.get(k) for k in keys}
        bad = [f"{k} {pk.get(k) or 'missing'} (client: {mine.get(k)})" for k in keys if pk.get(k) != mine.get(k)]
        if bad:
            raise FtcError(
                f"worker {addr}: versions differ from this client's: {', '.join(bad)}; "
                "install the same versions on every worker (results of two versions must not mix)"
            )
    # the same version can be other code (an edited checkout on another machine): the records name this
    # process's code digest (studies.batch.code_identity), so every worker must run the same sources
    mine_code = worker_code()
    for addr, code in sorted(client.run(worker_code).items()):
        if code != mine_code:
            raise FtcError(
                f"worker {addr}: its ftcreport code differs from this client's (source digest {code}, client: "
                f"{mine_code}); install the same checkout on every worker (results of two codes must not mix)"
            )
        if addr in out:
            out[addr]["code"] = code
    return out


def worker_code() -> str:
    """The package's source digest in the process that calls it (run on each worker by ``Client.run``)."""
    from ..storage.code_digest import code_digest

    return code_digest()


def execute(
    func: Callable[..., dict],
    tasks: Mapping[int, tuple],
    keys: Mapping[int, str],
    store: Callable[[dict], None],
    fail: Callable[[int, str], None],
    *,
    scheduler: str | None = None,
    workers: int = 2,
    in_process: bool = False,
    retries: int = 2,
    tick: Callable[[], None] = lambda: None,
    noun: str = "tasks",
) -> dict[str, Any]:
    """Run ``func(*tasks[i])`` for every ``i``; ``store(result)`` or ``fail(i, message)`` as each finishes.

    ``scheduler``: address of an existing Dask scheduler; otherwise a LocalCluster of ``workers``
    processes on 127.0.0.1 (or this process when ``in_process``), at most the number of tasks and the
    cores (as ``batch --jobs``; a note on stderr names the cap and ``noun``, what the tasks are).
    Returns what the cluster reported: ``{"workers": {address: versions}}`` (empty in-process, or with
    no task: then no cluster is started).
    """
    info: dict[str, Any] = {"workers": {}}
    if not tasks:  # nothing left to run (all stored): no cluster started, no worker note
        return info
    if in_process:
        for i, args in tasks.items():
            try:
                store(func(*args))
            except Exception as exc:  # a task that cannot run is recorded, the run goes on
                if (stop := interrupt_of(exc)) is not None:  # a stop signal, not the task's failure
                    raise stop from None
                fail(i, f"{type(exc).__name__}: {exc}")
            tick()
        return info
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = client = None
    try:
        # a stop signal while the local cluster starts is raised once it is up: a half-started LocalCluster
        # never reaches this code, so it could not be closed (distributed's atexit hook failed on it); a
        # connection to a --scheduler is not held so (a second signal goes through in any case)
        with deferred() if scheduler is None else contextlib.nullcontext():
            if scheduler is None:
                n, capped = worker_count(workers, len(tasks), "--workers", f"{noun} to run")
                if capped is not None:
                    note = f"ftcreport: note: --workers {workers}: capped at {n} ({capped})"
                    print(note, file=sys.stderr, flush=True)
                cluster = LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address=None,
                    # the scheduler's HTTP server (health, metrics) runs without a dashboard too: on a free port of
                    # the loopback, not 8787 (taken by another cluster: a warning line in the command's output)
                    scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                )
                client = Client(cluster)
            else:
                try:
                    client = Client(scheduler, timeout=30)
                except (OSError, TimeoutError) as exc:
                    raise FtcError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        info["workers"] = check_versions(client)
        client.register_plugin(WarmUp(quiet=cluster is not None), name=WarmUp.name)
        futures = {client.submit(func, *args, key=keys[i], retries=retries, pure=False): i for i, args in tasks.items()}
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                store(fut.result())
            except FtcError:
                raise
            except Exception as exc:
                fail(i, f"{type(exc).__name__}: {exc}")
            tick()
    except KeyboardInterrupt:  # a stop signal: the command's one message says it; Dask's shutdown is not news
        _silence_shutdown(client)
        raise
    finally:
        with shielded():  # the local workers are closed (and waited for) before the lock is released
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close(timeout=CLOSE_TIMEOUT_S)
    return info


def _silence_shutdown(client) -> None:
    """Dask's shutdown after a stop signal prints nothing: its loggers and its event loop's unhandled errors.

    A call the signal cut short (``get_versions``, ``register_plugin``: the scheduler's broadcast to
    the workers) goes on in the client's event loop; closing the cluster under it fails its comm, and
    asyncio logged "Future exception was never retrieved ... CommClosedError" with a traceback when
    the future was collected, possibly after the command's last line.  For the interrupted path only.
    """
    for name in ("distributed", "asyncio", "tornado"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    loop = getattr(getattr(client, "loop", None), "asyncio_loop", None)
    if loop is not None:
        loop.set_exception_handler(lambda loop, context: None)
