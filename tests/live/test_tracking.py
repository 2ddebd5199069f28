"""A frame without the marker: before any pose the input is shown unchanged; after one, the
last pose is kept and the frame counted as lost — the loop never stops on it.

Rejects: a live loop that raises (sequence's behaviour, right offline, wrong live), one that
renders a frame without a pose at the scene camera's pose (the virtual object would float
at a made-up place), and one that forgets the last pose.
"""

from __future__ import annotations

import numpy as np

from arlight.live import marker_video as mv
from arlight.live.loop import LiveCompositor, MarkerTracker, run_live
from arlight.live.setup import live_job
from arlight.live.sources import Captured
from arlight.methods import RenderSettings
from arlight.scene.load import load_scene
from arlight.sequence.frames import FrameSource, InputFrame
from tests.live.conftest import SIZE


def test_frames_without_the_marker_keep_the_loop_going(clip):
    job, calib, spec = live_job(load_scene(clip.scene), SIZE, "dir", RenderSettings(spp=1),
                                clip.calib, mv.MARKER, 30.0)
    tracker = MarkerTracker(calib, spec, job.camera)
    comp = LiveCompositor(job, tracker)
    blank = np.full((SIZE[1], SIZE[0], 3), 90, np.uint8)
    board = next(iter(FrameSource(clip.frames)))
    frames = [InputFrame(0, "blank", codes=blank), InputFrame(1, "board", codes=board.codes),
              InputFrame(2, "blank", codes=blank)]
    shown = []
    summary = run_live((Captured(f, 0.0) for f in frames), comp, on_frame=shown.append)
    assert summary.frames == 3 and summary.lost == 2 and tracker.lost == 2
    assert shown[0].pose is None and np.array_equal(shown[0].display, blank)
    assert shown[1].tracked and not shown[2].tracked
    assert np.array_equal(shown[2].pose, shown[1].pose)
    assert not np.array_equal(shown[2].display, blank)  # rendered: the bunny is there
