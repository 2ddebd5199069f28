"""The light server's newest state lights the next live frame (nearfield), read once a frame.

A fake client stands in for :class:`arlight.lightserver.client.LightClient` (its ``latest``
attribute is all the loop reads). Frame 0 renders under light A, then the "server" publishes
B and frame 1 renders under B: each composite must equal, bitwise, what
:class:`arlight.methods.nearfield.NearFieldClient` renders for that view and light on its
own (the independent path the `arlight client` command uses).

Rejects: a live loop that keeps the first light (frame 1 would equal A's render), reads the
light at prepare time only, or applies a state whose SH blocks do not match the objects.
"""

from __future__ import annotations

import numpy as np
import pytest

from arlight.live import marker_video as mv
from arlight.live.loop import LiveCompositor, MarkerTracker
from arlight.live.server_light import ServerLight
from arlight.live.setup import live_job
from arlight.live.sources import Captured
from arlight.methods import RenderSettings
from arlight.methods.nearfield import NearFieldClient
from arlight.nearfield.state import NearFieldLight
from arlight.scene.load import load_scene
from arlight.sequence.frames import FrameSource
from tests.live.conftest import SIZE


def _light(power: float, x: float, n_obj: int = 1) -> NearFieldLight:
    sh = np.zeros((n_obj, 9, 3))
    sh[:, 0] = 0.2 * power
    return NearFieldLight(np.array([[x, 0.6, 0.2]]), np.array([[0.0, -1.0, 0.0]]),
                          np.full((1, 3), power), np.array([0.05]), sh, sequence=int(power))


class FakeClient:
    latest = None


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_each_frame_renders_under_the_newest_server_light(clip):
    sc = load_scene(clip.scene)
    settings = RenderSettings(spp=1, seed=3)
    job, calib, spec = live_job(sc, SIZE, "nearfield", settings, clip.calib, mv.MARKER,
                                30.0, None, "clip")
    client = FakeClient()
    light = ServerLight(job, client)
    comp = LiveCompositor(job, MarkerTracker(calib, spec, job.camera), light=light)
    frames = list(FrameSource(clip.frames))[:2]
    a, b = _light(2.0, -0.2), _light(6.0, 0.4)
    client.latest = a
    f0 = comp(Captured(frames[0], 0.0))
    client.latest = b
    f1 = comp(Captured(frames[1], 0.0))
    client.latest = _light(9.0, 0.0, n_obj=3)  # does not match the world: skipped
    f2 = comp(Captured(frames[1], 0.0))
    assert light.updates == 2 and light.skipped == 1
    assert f0.stats["new_light"] == 1.0 and f2.stats["new_light"] == 0.0

    ref = NearFieldClient(job.world, settings.options, settings)

    def expected(fr, pose, lt):
        view = job.view(fr, pose=pose, objects={})
        return job.camera.transfer.to_display(ref.render(view, lt).composite)

    assert np.array_equal(f0.display, expected(frames[0], f0.pose, a))
    assert np.array_equal(f1.display, expected(frames[1], f1.pose, b))
    assert np.array_equal(f2.display, f1.display)  # the last good light kept
    assert not np.array_equal(f1.display, expected(frames[1], f1.pose, a))


def test_live_subscribes_to_a_running_light_server(clip, tmp_path):
    """End to end: `arlight live --light-server` against a LightServer on loopback applies
    its states (rejects a CLI that never wires the client to the loop)."""
    from arlight import cli
    from arlight.lightserver import LightServer
    from arlight.lightserver.producers import SyntheticMovingLight
    from tests.cli_invoke import MainRunner

    with LightServer(SyntheticMovingLight(vals=4, objects=[[0.1, 0.05, 0.14]]),
                     bind="tcp://127.0.0.1:*", rate_hz=30) as server:
        r = MainRunner().invoke(cli.app, [
            "live", clip.scene, "--video", clip.frames, "--calib", clip.calib, "--marker",
            mv.MARKER, "--no-studio", "--unpaced", "--max-frames", "2", "--light-server",
            server.endpoints[0], "--light-snapshot", server.endpoints[1], "--light-wait",
            "30", "--log", tmp_path / "log.jsonl"])
    assert r.exit_code == 0, r.output
    assert "2 frames composited" in r.output
    applied = int(r.output.split("light server: ")[1].split()[0])
    assert applied >= 1
