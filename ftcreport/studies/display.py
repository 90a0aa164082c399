"""The live progress display of ``ftcreport batch`` (rich, on a terminal's stderr).

Edge module (terminal output).  :class:`BatchDisplay` draws one overall bar (runs done of the
batch's total, elapsed time, an estimate of the time left) and one line per run a worker is on
(case / scheme, its fraction of simulated time); a finished run leaves the display, so a batch of
98 runs fits a 24-row terminal.  Nothing is drawn when stderr is not a terminal or with ``--quiet``.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # rich is imported only when a display is drawn
    from rich.console import Console, Group

__all__ = ["BatchDisplay"]


class BatchDisplay:
    """A batch's live display: an overall bar, a line per active run.

    The overall bar shows the finished runs of the total, the elapsed time and an estimate of the
    time left (rich's, from the bar's speed over the last minute); it advances by each active run's
    fraction of simulated time as well, so it moves between finishes.  A run's line appears when its
    worker starts it (its first run on a machine compiles the loop first: 0 % for about a minute) and
    leaves when it finishes.  At most the terminal's height less 4 run lines are shown, then a count
    of the others.  Without a console (:meth:`make`: stderr not a terminal, or ``--quiet``) it draws
    nothing.
    """

    @classmethod
    def make(cls, total: int, show_progress: bool, console: Console | None = None) -> BatchDisplay:
        """Live on a terminal's stderr (or on ``console``, a terminal); silent when stderr is not a
        terminal (piped, a CI log) or ``show_progress`` is off (``--quiet``)."""
        if console is None and show_progress and _stderr_is_terminal():
            from rich.console import Console

            console = Console(stderr=True)
        on = show_progress and console is not None and console.is_terminal and not console.is_dumb_terminal
        return cls(total, console if on else None)

    def __init__(self, total: int, console: Console | None) -> None:
        self.total = total
        self.console = console
        self.durations: dict[tuple[str, str], float] = {}  # simulated time of each run [s]
        self.fraction: dict[tuple[str, str], float] = {}  # active run -> fraction of its simulated time
        self.lines: dict[tuple[str, str], int] = {}  # active run -> its line (rich task id)
        self.done: set[tuple[str, str]] = set()
        self.live = None
        if console is None:
            return
        from rich.live import Live
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.overall = Progress(
            TextColumn("batch"),
            BarColumn(),
            TextColumn("{task.fields[done]}/{task.total:.0f} runs"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
            speed_estimate_period=60.0,
        )
        self.task = self.overall.add_task("batch", total=total, done=0)
        self.runs = Progress(  # its tasks are the active runs; drawn by __rich__, at most a screenful
            TextColumn("  {task.description}"),
            BarColumn(bar_width=20),
            TextColumn("{task.percentage:>3.0f} % of {task.total:g} s"),
            console=console,
        )
        self.live = Live(self, console=console, refresh_per_second=4, transient=False)

    def __rich__(self) -> Group:
        from rich.console import Group
        from rich.text import Text

        tasks = self.runs.tasks
        room = max(1, self.console.height - 4)
        shown = tasks if len(tasks) <= room else tasks[: room - 1]
        parts = [self.overall]
        if shown:
            parts.append(self.runs.make_tasks_table(shown))
        if len(shown) < len(tasks):
            parts.append(Text(f"  ... and {len(tasks) - len(shown)} more running"))
        return Group(*parts)

    def __enter__(self) -> BatchDisplay:
        if self.live is not None:
            self.live.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        """End the live display (its last state stays on the terminal: the overall bar)."""
        if self.live is not None:
            self.live.stop()

    def advanced(self, name: str, scheme: str, t: float) -> None:
        """A worker's report: run (name, scheme) is at simulated time ``t`` (0: it started)."""
        key = (name, scheme)
        if self.console is None or key in self.done:
            return
        duration = self.durations.get(key) or 1.0
        if key not in self.lines:
            self.lines[key] = self.runs.add_task(f"{name} / {scheme}", total=duration)
        self.fraction[key] = min(max(t / duration, 0.0), 1.0)
        self.runs.update(self.lines[key], completed=min(t, duration))
        self._overall()

    def finished(self, name: str, scheme: str) -> None:
        """Run (name, scheme) is over (stored, or failed): off the display, one more done."""
        key = (name, scheme)
        self.done.add(key)
        self.fraction.pop(key, None)
        if self.console is None:
            return
        line = self.lines.pop(key, None)
        if line is not None:
            self.runs.remove_task(line)
        self._overall()

    def _overall(self) -> None:
        self.overall.update(self.task, completed=len(self.done) + sum(self.fraction.values()), done=len(self.done))


def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False
