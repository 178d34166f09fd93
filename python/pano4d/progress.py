"""Progress of long work, the one way every phase reports it (train, animate, synth).

``Bars`` shows a rich bar per task on stderr: what runs, done / total, extra fields (a loss),
elapsed time and ETA. Disabled, its tasks do nothing, so the code that reports progress
never asks whether anyone is watching; a ``Task()`` made without bars is silent too.
"""

from __future__ import annotations

import math
from types import TracebackType

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class Task:
    """One bar of ``Bars``; silent when made without one."""

    def __init__(self, bar: Progress | None = None, task: TaskID | None = None) -> None:
        self._bar, self._task = bar, task

    def update(self, completed: float, **fields: float | str) -> None:
        """Set the done count and the extra fields; a float shows four decimals, or '-'
        while it is not finite (nothing measured yet)."""
        if self._bar is None or self._task is None:
            return
        shown = {name: _show(value) for name, value in fields.items()}
        self._bar.update(self._task, completed=completed, **shown)

    def advance(self, description: str | None = None) -> None:
        """One step done; ``description`` (if given) says what was just done."""
        if self._bar is None or self._task is None:
            return
        if description is None:
            self._bar.advance(self._task)
        else:
            self._bar.update(self._task, advance=1, description=description)

    def remove(self) -> None:
        """Take this bar off the display (its work is over)."""
        if self._bar is not None and self._task is not None:
            self._bar.remove_task(self._task)
            self._task = None


class Bars:
    """Progress bars with a column ``name {value}`` for each of ``fields``; use as a context
    manager, then ``task(description, total)`` per piece of work."""

    def __init__(
        self,
        *fields: str,
        enabled: bool = True,
        console: Console | None = None,
        transient: bool = False,
        whole_run_eta: bool = False,
    ) -> None:
        self._fields = fields
        self._bar: Progress | None = None
        if enabled:
            self._bar = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                *(TextColumn(f"{name} {{task.fields[{name}]}}") for name in fields),
                TimeElapsedColumn(),
                TextColumn("ETA"),
                TimeRemainingColumn(),
                console=console,
                transient=transient,
                # rich estimates speed over the last 30 s; work whose items take minutes
                # (a batch of scenes) needs the throughput of the whole run.
                speed_estimate_period=math.inf if whole_run_eta else 30.0,
            )

    def __enter__(self) -> Bars:
        if self._bar is not None:
            self._bar.start()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        if self._bar is not None:
            self._bar.stop()

    def print(self, text: str) -> None:
        """A line of rich markup above the bars."""
        if self._bar is not None:
            self._bar.console.print(text, highlight=False)

    def task(self, description: str, total: int | None, completed: int = 0) -> Task:
        """A new bar, ``completed`` of ``total`` done (a resumed stage starts part-way);
        ``total=None`` for work whose size is not known (the bar pulses)."""
        if self._bar is None:
            return Task()
        fields = dict.fromkeys(self._fields, "-")
        size = None if total is None else max(total, 1)
        task = self._bar.add_task(description, total=size, completed=completed, **fields)
        return Task(self._bar, task)


def _show(value: float | str) -> str:
    if isinstance(value, str):
        return value
    return f"{value:.4f}" if math.isfinite(value) else "-"
