"""The terminal's progress bars: the ``rich`` adapter of :mod:`arlight.progress`.

The command line installs :class:`RichSink` for the duration of a command
(:func:`terminal_bars`); every engine's :class:`arlight.progress.Task` then shows as one bar
on stderr — description, bar, done/total, the task's status text, elapsed and remaining
time — and disappears when the task closes. Nothing outside the CLI imports ``rich`` for
progress.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

from arlight import progress


class RichSink:
    """A :data:`arlight.progress.Sink` drawing one ``rich`` bar per open task."""

    def __init__(self, console=None) -> None:
        self._console = console
        self._bars = None  # made at the first event: rich is imported only when a bar shows
        self._tasks: dict[int, int] = {}
        self._lock = threading.Lock()

    def _start(self):
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._bars = Progress(TextColumn("{task.description}"), BarColumn(),
                              MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                              TimeElapsedColumn(), TimeRemainingColumn(),
                              console=self._console or Console(stderr=True), transient=True)
        self._bars.start()
        return self._bars

    def __call__(self, event: progress.Event) -> None:
        with self._lock:
            bars = self._bars or self._start()
            tid = self._tasks.get(event.task)
            if tid is None:
                tid = self._tasks[event.task] = bars.add_task(
                    event.label, total=event.total, completed=event.done, info=event.info)
            bars.update(tid, completed=event.done, total=event.total, info=event.info)
            if event.finished:
                bars.remove_task(tid)
                del self._tasks[event.task]

    def stop(self) -> None:
        """Remove the bars (at the end of the command)."""
        with self._lock:
            if self._bars is not None:
                self._bars.stop()
                self._bars = None
                self._tasks.clear()


@contextlib.contextmanager
def terminal_bars(console=None) -> Iterator[RichSink]:
    """Show every task's progress on the terminal inside the block."""
    bars = RichSink(console)
    try:
        with progress.sink(bars):
            yield bars
    finally:
        bars.stop()


__all__ = ["RichSink", "terminal_bars"]
