"""arlight.interrupts: signals held during native calls and blocked in native threads."""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import pytest

from arlight import interrupts


def _blocked_in_thread(native_id: int) -> set[int]:
    """The signals thread ``native_id`` of this process blocks (from /proc)."""
    text = Path(f"/proc/self/task/{native_id}/status").read_text()
    mask = int(next(ln for ln in text.splitlines() if ln.startswith("SigBlk")).split()[1], 16)
    return {s for s in (signal.SIGINT, signal.SIGTERM) if mask >> (int(s) - 1) & 1}


@pytest.fixture
def handler():
    """A handler like the CLI's: defers inside a shield, else raises."""
    seen: list[str] = []

    def on_signal(signum, _frame):
        if interrupts.deferring():
            seen.append("deferred")
            interrupts.defer(signum)
            return
        seen.append("raised")
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_signal)
    yield seen
    signal.signal(signal.SIGINT, previous)


def test_signal_inside_a_shield_is_raised_when_it_ends(handler):
    """Bug caught: a Ctrl-C raised inside the native call (a callback from Mitsuba's variant
    switch turned it into a RuntimeError, read as bad input)."""
    reached_end_of_block = False
    with pytest.raises(KeyboardInterrupt):
        with interrupts.shielded():
            signal.raise_signal(signal.SIGINT)
            reached_end_of_block = True
    assert reached_end_of_block
    assert handler[-1] == "raised"
    assert not interrupts.deferring()


def test_threads_started_inside_a_shield_block_the_signals():
    """Bug caught: Dr.Jit's worker threads receiving SIGINT (EINTR in native code: abort)."""
    if not Path("/proc/self/task").is_dir():
        pytest.skip("needs /proc")
    ids: dict[str, int] = {}
    go = threading.Event()

    def worker(name):
        ids[name] = threading.get_native_id()
        go.wait(10)

    with interrupts.shielded():
        inside = threading.Thread(target=worker, args=("inside",))
        inside.start()
    outside = threading.Thread(target=worker, args=("outside",))
    outside.start()
    try:
        while len(ids) < 2:
            pass
        assert _blocked_in_thread(ids["inside"]) == {signal.SIGINT, signal.SIGTERM}
        assert _blocked_in_thread(ids["outside"]) == set()
        assert _blocked_in_thread(threading.get_native_id()) == set()  # main restored
    finally:
        go.set()
        inside.join()
        outside.join()


def test_test_point_only_fires_when_named(monkeypatch, handler):
    monkeypatch.setenv("ARLIGHT_TEST_SIGNAL_AT", "kernel")
    interrupts.test_point("scene")
    assert handler == []
    with pytest.raises(KeyboardInterrupt):
        interrupts.test_point("kernel")
