"""Frames that arrive while one renders are dropped, never queued (fake clock, fake renderer).

The clock is simulated: the fake renderer advances it by its render time, the paced source
sleeps by advancing it. Nothing depends on the real machine's speed.

Rejects: a loop that queues (renders every frame: latency grows without bound), one that
takes the *oldest* waiting frame instead of the newest, drops that are not counted (or
counted twice), a capture time that is the hand-over time rather than the frame's arrival
(latency would miss the wait), and a source that busy-returns a frame it already handed over.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from arlight.live.loop import LiveFrame, run_live
from arlight.live.sources import CameraSource, Captured, paced, unpaced
from arlight.sequence.frames import InputFrame


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0
        self.slept = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.slept += max(seconds, 0.0)
        self.t += max(seconds, 0.0)


def _frames(n: int):
    img = np.zeros((2, 2, 3), np.uint8)
    return (InputFrame(i, f"f{i}", codes=img) for i in range(n))


def _slow(clock: FakeClock, seconds: float):
    def process(cap: Captured) -> LiveFrame:
        clock.t += seconds  # the "render"
        return LiveFrame(cap.frame.index, cap.frame.codes, None, True,
                         captured_at=cap.captured_at, dropped=cap.dropped)
    return process


def _expected(n: int, fps: float, render: float) -> list[tuple[int, float]]:
    """Independently: the renderer is free at t; the newest arrived frame is ⌊t·fps⌋ (or it
    waits for the next one); (frame, time taken) in a simple simulation."""
    taken, t, last = [], 0.0, -1
    while True:
        newest = min(math.floor(t * fps + 1e-9), n - 1)
        if newest <= last:
            if last + 1 >= n:
                return taken
            newest = last + 1
            t = newest / fps
        taken.append((newest, t))
        last = newest
        t += render


def test_a_slow_renderer_gets_the_newest_frame_and_drops_are_counted():
    clock = FakeClock()
    n, fps, render = 40, 10.0, 0.25
    shown: list[LiveFrame] = []
    summary = run_live(paced(_frames(n), fps, clock), _slow(clock, render), clock=clock,
                       on_frame=shown.append)
    idx = [f.index for f in shown]
    expected = _expected(n, fps, render)
    assert idx == [i for i, _ in expected]
    assert idx[:5] == [0, 2, 5, 7, 10]  # worked by hand: t = 0, .25, .5, .75, 1.0
    assert summary.dropped == sum(f.dropped for f in shown) == n - len(shown) - 0
    assert [f.dropped for f in shown][1:5] == [1, 2, 1, 2]
    # latency = wait since the frame arrived + render: at most one frame period + render
    lat = np.array([f.latency for f in shown])
    assert np.allclose(lat, [t - i / fps + render for i, t in expected])
    assert lat.max() > render + 0.01  # some frames waited after arriving
    assert np.all(lat <= render + 1 / fps + 1e-9) and np.all(lat >= render - 1e-9)
    assert summary.frames == len(shown)


def test_a_fast_renderer_waits_for_each_frame_and_drops_nothing():
    clock = FakeClock()
    n, fps, render = 12, 10.0, 0.03
    shown: list[LiveFrame] = []
    summary = run_live(paced(_frames(n), fps, clock), _slow(clock, render), clock=clock,
                       on_frame=shown.append)
    assert [f.index for f in shown] == list(range(n))
    assert summary.dropped == 0
    assert np.allclose([f.latency for f in shown], render)  # captured at arrival
    assert math.isclose(clock.slept, n * (1 / fps - render) - (1 / fps - render), rel_tol=1e-9)
    assert math.isclose(summary.seconds, (n - 1) / fps + render, rel_tol=1e-9)


def test_unpaced_takes_every_frame_in_order():
    clock = FakeClock()
    shown: list[LiveFrame] = []
    summary = run_live(unpaced(_frames(7), clock), _slow(clock, 5.0), clock=clock,
                       on_frame=shown.append)
    assert [f.index for f in shown] == list(range(7)) and summary.dropped == 0


class FakeCapture:
    """A VideoCapture whose read() returns frames the test releases one by one."""

    def __init__(self) -> None:
        self.gate = threading.Semaphore(0)
        self.served = 0
        self.done = threading.Event()
        self.limit = 1 + 5  # the probe frame + five more

    def isOpened(self) -> bool:  # noqa: N802 — OpenCV's name
        return True

    def set(self, *a) -> bool:
        return True

    def get(self, *a) -> float:
        return 30.0

    def read(self):
        if self.served >= self.limit:  # the reader is back after putting the last frame
            self.done.set()
        if self.served >= 1:  # the first read is CameraSource's probe
            self.gate.acquire()
        if self.served >= self.limit:
            return False, None
        img = np.full((2, 2, 3), self.served, np.uint8)
        self.served += 1
        return True, img

    def release(self) -> None:
        pass


def test_the_camera_mailbox_keeps_the_newest_frame_and_counts_overwrites():
    cap = FakeCapture()
    src = CameraSource(0, capture=cap)
    clock = FakeClock()
    src.start(clock)
    it = src.captures(clock)
    for _ in range(5):  # five frames arrive before the loop asks for one
        cap.gate.release()
    assert cap.done.wait(60)
    first = next(it)
    # frames 1..5 arrived; the newest (5) is handed over, 1..4 were overwritten (dropped)
    assert int(first.frame.codes[0, 0, 0]) == 5 and first.dropped == 4
    cap.gate.release()  # the end of the stream
    assert list(it) == []
