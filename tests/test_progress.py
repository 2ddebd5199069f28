"""The progress protocol: engines report tasks to a sink; the terminal bar is an adapter."""

from __future__ import annotations

import io

from arlight import progress
from arlight.cli_progress import RichSink
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize
from tests.conftest import area_light_scene, with_constant_frame


def _collect():
    events: list[progress.Event] = []
    return events, events.append


def test_a_render_reports_its_samples_and_ends():
    """Bugs caught: a pass loop that reports to a terminal bar of its own (nothing reaches
    the sink), counts passes instead of samples, or never closes its task."""
    scene = with_constant_frame(parse_scene(area_light_scene(8, 6)))
    events, sink = _collect()
    with progress.sink(sink):
        get_method("reference")(scene, RenderSettings(spp=8, progress=True))
    assert events and events[-1].finished and events[-1].done == 8 == events[-1].total
    assert {e.label for e in events} == {"reference"}
    events.clear()
    with progress.sink(sink):
        get_method("reference")(scene, RenderSettings(spp=8, progress=False))
    assert events == []  # progress=False: silent


def test_synthesis_reports_batches():
    world = parse_scene(area_light_scene(8, 6, virtual=False))
    events, sink = _collect()
    with progress.sink(sink):
        synthesize(world, spp=4, batches=2, use_cache=False, progress=True)
    assert events[-1].finished and events[-1].done == events[-1].total >= 2


def test_no_sink_reports_nowhere_and_sinks_nest():
    events, sink = _collect()
    with progress.task("x", 3) as t:
        t.advance()
    assert events == []
    with progress.sink(sink):
        with progress.sink(None):
            progress.task("inner", 1).close()
        with progress.task("outer", 2) as t:
            t.advance(2, info="ok")
    assert [(e.label, e.done, e.info, e.finished) for e in events] == [
        ("outer", 0.0, "", False), ("outer", 2.0, "ok", False), ("outer", 2.0, "ok", True)]


def test_the_rich_adapter_draws_and_removes_bars():
    from rich.console import Console

    out = io.StringIO()
    bars = RichSink(Console(file=out, force_terminal=True, width=100))
    with progress.sink(bars):
        with progress.task("demo render", 4) as t:
            t.advance(2, info="RMSE 0.1")
            assert len(bars._tasks) == 1
    assert bars._tasks == {}
    bars.stop()
    assert "demo render" in out.getvalue()


def test_a_done_total_callback_reports_one_task():
    """The (done, total) form the precomputations call (PRT transfer, occlusion fields)."""
    events, sink = _collect()
    with progress.sink(sink):
        report = progress.reporter("prt transfer bunny")
        for done in (10, 20, 30):
            report(done, 30)
    assert [e.done for e in events] == [0, 10, 20, 30, 30]
    assert events[-1].finished and len({e.task for e in events}) == 1
