"""A command's processes end with it: stop signals, worker processes tied to their parent.

Stop signals.  SIGINT (Ctrl-C), SIGTERM (``kill``, a service manager, a CI timeout) and SIGHUP (the
terminal closed) all stop a command the same way (:func:`handle_stop_signals`): the first one
raises :class:`Interrupted` (a ``KeyboardInterrupt``) in the main thread, so every command unwinds
through its ``finally`` blocks: worker processes are terminated and waited for, temporary files
removed, and the output directory's lock released last (:func:`ftcreport.storage.store.output_lock`).
That cleanup runs :func:`shielded`: a signal meanwhile is dropped, so it is not cut short (it
waits at most 5 s for the workers, then kills them); elsewhere a second signal raises again (an
interrupt swallowed by a library is not the end of it), and SIGKILL ends everything.  The exit code
is the shell's convention for a death by that signal, 128 + its number: 130 (SIGINT), 143
(SIGTERM), 129 (SIGHUP).

Worker processes.  A worker must not outlive its command when the command is SIGKILLed (no
``finally`` runs then).  :func:`die_with_parent` asks Linux to SIGKILL the worker when its
parent ends (``prctl(PR_SET_PDEATHSIG)``), and checks that the parent did not end before the
request; elsewhere a daemon thread polls the parent's pid.  A batch worker also holds its
command's lock (:func:`ftcreport.storage.store.lock_fd`), so the lock is free only when the last of them
is gone, and checks before each write that its parent is alive
(:func:`ftcreport.storage.store.set_write_guard`).
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import sys
import threading
import time
from collections.abc import Iterable, Iterator

__all__ = [
    "STOP_SIGNALS",
    "Interrupted",
    "deferred",
    "die_with_parent",
    "exit_code",
    "handle_stop_signals",
    "interrupt_of",
    "shielded",
    "stop_pool",
    "stop_processes",
]

#: the signals that stop a command cleanly (SIGHUP does not exist on Windows)
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


class Interrupted(KeyboardInterrupt):
    """A stop signal reached the command (a ``KeyboardInterrupt``, so every interrupt path handles it)."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def exit_code(exc: BaseException) -> int:
    """128 + the signal's number (the shell's code for a death by that signal); Ctrl-C: 130."""
    return 128 + int(getattr(exc, "signum", signal.SIGINT))


def interrupt_of(exc: BaseException | None) -> KeyboardInterrupt | None:
    """The interrupt behind ``exc``: itself, or the cause or context it was raised from, or None.

    A stop signal whose handler ran while compiled code was being called comes back wrapped: numba's
    dispatcher returns "a result with an exception set" and Python raises SystemError from it.
    """
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


_shield: list[int] = [0]  # > 0: inside cleanup code (shielded()): a stop signal is not raised there
_defer: list[int] = [0, 0]  # [depth of deferred(), the first stop signal met inside it (0: none)]

#: Python that C code calls back into: llvmlite (its object cache hands LLVM a cached kernel's machine code)
#: and numba's unpickling from compiled code.  An exception raised there is printed and dropped, and the C
#: caller, handed nothing, crashes (CI, round 3: SIGTERM in ``_raw_object_cache_getbuffer``, exit -11).
_CALLBACK_FILES = (f"{os.sep}llvmlite{os.sep}", os.path.join("numba", "core", "serialize.py"))


def _on_stop_signal(signum, frame) -> None:
    """Raise :class:`Interrupted`; not inside cleanup (:func:`shielded`), a finaliser or a callback of the collector.

    Python runs signal handlers between bytecodes, also inside garbage-collection callbacks,
    finalisers and callbacks from C (:data:`_CALLBACK_FILES`), where an exception is printed
    ("Exception ignored in ...", with a traceback) and dropped: the command would go on as if nothing
    happened, or its C caller crash.  There the signal is sent again 50 ms later instead.  In cleanup
    code it is dropped: the cleanup is already stopping the command.
    """
    if _shield[0] > 0:
        return
    if _defer[0] > 0 and not _defer[1]:  # the first is held; a second one stops at once
        _defer[1] = int(signum)
        return
    callbacks = {getattr(getattr(cb, "__func__", cb), "__code__", None) for cb in gc.callbacks}
    f, depth = frame, 0
    while f is not None and depth < 12:
        code = f.f_code
        if (
            code.co_name == "__del__"
            or code.co_filename.endswith("weakref.py")
            or code in callbacks
            or any(part in code.co_filename for part in _CALLBACK_FILES)
        ):
            threading.Timer(0.05, os.kill, (os.getpid(), signum)).start()
            return
        f, depth = f.f_back, depth + 1
    raise Interrupted(signum)


@contextlib.contextmanager
def shielded() -> Iterator[None]:
    """Inside: stop signals are not raised (cleanup that must finish: workers stopped, partial files
    removed, the lock released).  Keep it bounded: a stop signal is dropped, not deferred."""
    _shield[0] += 1
    try:
        yield
    finally:
        _shield[0] -= 1


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Inside: a stop signal is held, and raised (:class:`Interrupted`) as the block ends.

    For a step that cannot be cut in the middle yet must not lose the signal: starting a Dask
    LocalCluster, whose half-started object the caller never receives, so cannot close (its
    atexit hook then failed on it: "AssertionError: Status.init").  Keep it bounded.
    """
    _defer[0] += 1
    try:
        yield
    finally:
        _defer[0] -= 1
        if _defer[0] == 0 and _defer[1]:
            signum, _defer[1] = _defer[1], 0
            raise Interrupted(signum)


@contextlib.contextmanager
def handle_stop_signals() -> Iterator[None]:
    """Inside: SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (SIGTERM and SIGHUP unless this
    process was started ignoring them, as ``nohup`` does for SIGHUP).  After: SIGINT is ignored (the
    command is over, done or reported: a Ctrl-C from there to the exit has nothing left to stop, and
    uncaught it would end the process with no message); SIGTERM and SIGHUP get their handlers back
    (by default they end the process, which has nothing left to clean).  Main thread only."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    # a SIGTERM or SIGHUP the command was started ignoring stays ignored (nohup: the command outlives its terminal)
    before = {sig: old for sig, old in before.items() if sig == signal.SIGINT or old is not signal.SIG_IGN}
    for sig in before:
        signal.signal(sig, _on_stop_signal)
    try:
        yield
    finally:
        for sig, old in before.items():
            restore = signal.SIG_IGN if sig == signal.SIGINT else old
            signal.signal(sig, restore if restore is not None else signal.SIG_DFL)


def die_with_parent(parent: int) -> None:
    """End this process (SIGKILL) when its parent ``parent`` ends, however the parent ends.

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (the kernel sends it when the thread that started
    this process ends; a batch starts its workers from its main thread).  If the parent is already
    gone (it died before the request), exit now.  Elsewhere, or if prctl is unavailable: a daemon
    thread checks the parent's pid every 0.2 s.
    """
    if _set_pdeathsig():
        if os.getppid() != parent:
            os._exit(1)
        return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.2)
        os._exit(1)

    threading.Thread(target=watch, name="ftcreport-parent-watch", daemon=True).start()


def _set_pdeathsig() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1  # <linux/prctl.h>
        return libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def stop_processes(procs: Iterable, grace: float = 5.0) -> None:
    """Terminate ``procs`` (multiprocessing processes) and wait until they are gone.

    SIGTERM first; whatever still runs after ``grace`` seconds is killed (SIGKILL).
    """
    procs = list(procs)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    deadline = time.monotonic() + grace
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        with contextlib.suppress(Exception):
            if p.is_alive():
                p.kill()
                p.join(1.0)


def stop_pool(pool, grace: float = 5.0) -> None:
    """Stop a ``ProcessPoolExecutor`` now: its workers terminated (:func:`stop_processes`), the runs still
    waiting cancelled, and its manager thread ended before this returns (at most ``grace`` more seconds).

    The manager thread closes the pool's wake-up pipe as it ends.  A pool left to end on its own after
    ``shutdown(wait=False)`` raced with the interpreter's exit, which writes to that pipe
    (``concurrent.futures.process._python_exit``): "Exception ignored ... OSError: [Errno 9] Bad file
    descriptor" after the command's last line (CI, round 3, a batch stopped by SIGHUP).  The wait runs in
    a daemon thread, so a manager that never ends costs ``grace`` seconds, not the command.
    """
    stop_processes(list((getattr(pool, "_processes", None) or {}).values()), grace=grace)
    ender = threading.Thread(
        target=pool.shutdown, kwargs={"wait": True, "cancel_futures": True}, name="ftcreport-pool-stop", daemon=True
    )
    ender.start()
    ender.join(grace)
