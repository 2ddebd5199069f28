"""Ctrl-C that never lands inside native code, and the test points that prove it.

A SIGINT (or SIGTERM) turns into a Python exception in the main thread that unwinds the
command and removes its staged output (:mod:`arlight.cli`). Two places must never see it:

* **native worker threads** (Dr.Jit's thread pool, LLVM, OpenBLAS): a signal delivered to
  one of them interrupts its system call (``EINTR``), which native code may not expect (a
  run ended by SIGABRT instead of exit 130). Threads inherit their creator's signal mask, so
  the places that create them — the start-up imports and Mitsuba's variant switch — run
  inside :func:`shielded`, and every thread started there blocks SIGINT and SIGTERM for
  its whole life;
* **native calls of the main thread** that call back into Python (Mitsuba's variant switch
  imports Python modules; scene construction; a render kernel's launch): an exception raised
  in such a callback is rewrapped by the native layer as a ``RuntimeError`` — which then
  reads as bad input (exit 2) — or ends the process. Inside :func:`shielded` the main
  thread blocks the signals too and the Python handler defers them; they are delivered the
  moment the shield ends, before the next line of the command runs.

A shield is therefore short: around one native call, never around a whole render (a Ctrl-C
waits at most for the call in progress, as it does anyway for native code).

Test points: :func:`test_point` sends this process the signal named by
``ARLIGHT_TEST_SIGNAL`` (default SIGINT) when the environment variable
``ARLIGHT_TEST_SIGNAL_AT`` names the point. The interruption tests use it to interrupt a run
at chosen phases (``startup``, ``variant``, ``scene``, ``kernel``, ``write``) instead of at
a random wall time.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})
"""The signals that stop a command."""

_depth = 0
_deferred: list[int] = []


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def deferring() -> bool:
    """True while the main thread is inside a :func:`shielded` block (a signal handler then
    calls :func:`defer` instead of raising)."""
    return _depth > 0


def defer(signum: int) -> None:
    """Remember ``signum`` until the current shield ends (called by the signal handler)."""
    _deferred.append(signum)


@contextlib.contextmanager
def shielded() -> Iterator[None]:
    """Run a native call with SIGINT/SIGTERM held: blocked in this thread and in every thread
    started inside, deferred by the Python handler; delivered when the block ends.

    Outside the main thread it does nothing (signals are handled by the main thread only).
    Nested shields deliver at the end of the outermost one.
    """
    global _depth
    if not _in_main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)  # a blocked signal runs now
        if _depth == 0 and _deferred:
            signum = _deferred[0]
            _deferred.clear()
            signal.raise_signal(signum)


def test_point(name: str) -> None:
    """Interrupt this process here when ``ARLIGHT_TEST_SIGNAL_AT`` is ``name`` (tests only).

    The signal is sent synchronously (``raise_signal``): it is handled exactly as a Ctrl-C
    arriving at this point, inside whatever shield is active.
    """
    if os.environ.get("ARLIGHT_TEST_SIGNAL_AT") != name:
        return
    sig = getattr(signal, os.environ.get("ARLIGHT_TEST_SIGNAL", "SIGINT"), signal.SIGINT)
    if _depth > 0:  # blocked in this thread: it stays pending until the shield ends
        os.kill(os.getpid(), sig)
    else:
        signal.raise_signal(sig)


__all__ = ["SIGNALS", "defer", "deferring", "shielded", "test_point"]
