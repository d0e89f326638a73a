"""Progress of a long step of known size: a rich progress bar on a terminal, a line per tenth of the work in a log.

A rich bar alone says nothing where output goes to a file or a pipe (a batch job's log, ``agrinerf-demo | tee``): it
draws only on a terminal. :func:`work_progress` picks by the console it writes to, so a command that runs for minutes
shows that it runs on both.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from typing import Iterator, Optional

from rich.console import Console

LOG_FRACTION = 0.1
"""Share of the work between two progress lines in a log."""


class WorkProgress:
    """What a step calls as its work advances (:meth:`advance`); made by :func:`work_progress`."""

    def __init__(self, label: str, total: int, console: Console, fraction: float = LOG_FRACTION) -> None:
        self.label, self.total, self.console = label, max(int(total), 0), console
        self.done = 0
        self.started = time.perf_counter()
        self._bar = None
        self._task = None
        # units of work between two log lines: the most that stays within ``fraction`` of the work
        self._step = max(1, math.floor(self.total * fraction))
        self._reported = 0

    def advance(self, amount: int = 1) -> None:
        """Count ``amount`` more units of work done."""
        self.done = min(self.done + amount, self.total) if self.total else self.done + amount
        if self._bar is not None:
            self._bar.update(self._task, completed=self.done)
            return
        if self.done - self._reported >= self._step or (self.done == self.total and self.done > self._reported):
            self._reported = self.done
            self.console.print(self.line(), soft_wrap=True, highlight=False)

    def line(self) -> str:
        """The log line: the share done, the count, the time spent and an estimate of the time left."""
        elapsed = time.perf_counter() - self.started
        share = self.done / self.total if self.total else 1.0
        left = f", about {elapsed * (1 - share) / share:.0f} s left" if 0 < share < 1 else ""
        return f"{self.label}: {100 * share:.0f}% ({self.done}/{self.total}) in {elapsed:.0f} s{left}"


@contextmanager
def work_progress(
    label: str, total: int, console: Optional[Console] = None, fraction: float = LOG_FRACTION
) -> Iterator[WorkProgress]:
    """Show the progress of ``total`` units of work named ``label`` on ``console`` (stderr by default): a transient
    rich bar where it is a terminal, else a line at each ``fraction`` of the work."""
    console = console if console is not None else Console(stderr=True)
    progress = WorkProgress(label, total, console, fraction)
    if not console.is_terminal:
        yield progress
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())  # fmt: skip
    with Progress(*columns, console=console, transient=True) as bar:
        progress._bar, progress._task = bar, bar.add_task(label, total=total)
        yield progress
