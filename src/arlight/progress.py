"""Progress of long loops: one protocol for every engine; the terminal bar lives in the CLI.

An engine opens a :class:`Task` (``with progress.task("synthetic photo", total=n) as t:
... t.advance()``) and knows nothing of terminals. Each change is reported as an
:class:`Event` to the *sink*: a plain callback set with :func:`use_sink` (the CLI installs a
``rich`` bar, :mod:`arlight.cli_progress`; a notebook or a server may install its own). With
no sink — a library call, a test, a Ray worker — reporting costs a function call and prints
nothing.
"""

from __future__ import annotations

import contextlib
import itertools
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass


@dataclass(frozen=True)
class Event:
    """One change of a task: ``done`` of ``total`` units (``total`` None: open-ended).

    ``info``: a short status text (e.g. ``"RMSE 0.0123"``, ``"2.1 frames/s"``);
    ``finished``: the task has ended (its last event).
    """

    task: int
    label: str
    done: float
    total: float | None
    info: str = ""
    finished: bool = False


Sink = Callable[[Event], None]
"""Receives every :class:`Event` (called from the thread that reports)."""

_sink: Sink | None = None
_ids = itertools.count(1)
_lock = threading.Lock()


def use_sink(sink: Sink | None) -> Sink | None:
    """Install ``sink`` (None: report nowhere); returns the previous one."""
    global _sink
    with _lock:
        previous, _sink = _sink, sink
    return previous


@contextlib.contextmanager
def sink(s: Sink | None) -> Iterator[None]:
    """Report to ``s`` inside the block, to the previous sink after it."""
    previous = use_sink(s)
    try:
        yield
    finally:
        use_sink(previous)


class Task:
    """A long loop's progress: ``advance`` after each unit, ``close`` (or leave the ``with``
    block) at the end. A disabled task reports nothing."""

    def __init__(self, label: str, total: float | None, *, done: float = 0.0,
                 enabled: bool = True) -> None:
        self.id = next(_ids)
        self.label = label
        self.total = total
        self.done = done
        self.info = ""
        self.enabled = enabled
        self.closed = False
        self._emit()

    def _emit(self, finished: bool = False) -> None:
        s = _sink
        if self.enabled and s is not None:
            s(Event(self.id, self.label, self.done, self.total, self.info, finished))

    def advance(self, amount: float = 1.0, info: str | None = None) -> None:
        """``amount`` more units done; ``info`` replaces the status text when given."""
        self.done += amount
        if info is not None:
            self.info = info
        self._emit()

    def close(self) -> None:
        """Report the end (once)."""
        if not self.closed:
            self.closed = True
            self._emit(finished=True)

    def __enter__(self) -> Task:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def task(label: str, total: float | None, *, done: float = 0.0,
         enabled: bool = True) -> Task:
    """Open a :class:`Task` (``enabled`` False: a silent one, for a ``progress=False``)."""
    return Task(label, total, done=done, enabled=enabled)


def reporter(label: str) -> Callable[[float, float], None]:
    """A ``progress(done, total)`` callback (the form the PRT and occlusion precomputations
    take) that reports through one task, opened at its first call and closed when
    ``done >= total``."""
    state: dict[str, Task] = {}

    def report(done: float, total: float) -> None:
        t = state.get("task")
        if t is None or t.closed:
            t = state["task"] = Task(label, total)
        t.advance(done - t.done)
        if done >= total:
            t.close()

    return report


__all__ = ["Event", "Sink", "Task", "reporter", "sink", "task", "use_sink"]
