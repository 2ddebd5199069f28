"""`arlight live` on a synthetic marker video equals `arlight sequence --poses marker`.

Both commands run in this process on the same four frames; live unpaced (every frame, in
order) records its composites as PNG and logs its poses. Since live renders each frame
through sequence's own per-frame function (`render_frame`) with the pose from sequence's own
per-frame tracking step (`marker_pose`), poses and composites must be **bitwise** equal.

Rejects: a live loop that does not undistort the frames, uses the scene camera's intrinsics
instead of the calibration's, registers on another image than sequence does, renders with
another seed or settings, or re-orders, skips or repeats frames when unpaced; and poses that
are not the registration at all (checked against the orbit that made the frames, within
3 mm and 0.5°: an independent ground truth).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.io.images import read_ldr
from arlight.live import marker_video as mv
from arlight.methods import RenderSettings
from arlight.scene.load import load_scene
from arlight.sequence.build import build_job
from arlight.sequence.frames import FrameSource
from tests.cli_invoke import MainRunner

METHOD = "dir"


@pytest.mark.parametrize("method, with_depth", [(METHOD, False), ("probeless", True)])
def test_live_equals_sequence_on_the_same_frames(clip, clip_depth, tmp_path, method,
                                                 with_depth):
    """dir from RGB; probeless with the frames' depth images (RGB-D: the depth must reach
    the method in both, as the same per-frame image)."""
    from arlight import cli

    run = MainRunner()
    seq_out = tmp_path / "seq"
    depth = ["--depth", clip_depth] if with_depth else []
    r = run.invoke(cli.app, ["sequence", clip.scene, "--frames", clip.frames, "--poses",
                             "marker", "--calib", clip.calib, "--marker", mv.MARKER,
                             "-m", method, "-o", seq_out, "--video", "none",
                             "--render-scale", "2", *depth])
    assert r.exit_code == 0, r.output
    rec, log = tmp_path / "rec", tmp_path / "live.jsonl"
    r = run.invoke(cli.app, ["live", clip.scene, "--video", clip.frames, "--calib",
                             clip.calib, "--marker", mv.MARKER, "-m", method, "--unpaced",
                             "--no-studio", "--record", rec, "--log", log, *depth])
    assert r.exit_code == 0, r.output
    assert "4 frames composited" in r.output and "0 dropped" in r.output
    lines = [json.loads(x) for x in log.read_text().splitlines()]
    assert [x["frame"] for x in lines] == [0, 1, 2, 3]
    assert all(x["tracked"] and x["dropped_before"] == 0 for x in lines)
    # the poses: bitwise sequence's, and the orbit's within the registration's accuracy
    job = build_job(load_scene(clip.scene), FrameSource(clip.frames), METHOD,
                    RenderSettings(spp=1), poses="marker", calib=clip.calib,
                    marker=mv.MARKER)
    for x, seq_pose, truth in zip(lines, job.poses, clip.poses, strict=True):
        live_pose = np.asarray(x["pose"]).reshape(4, 4)
        assert np.array_equal(live_pose, seq_pose)
        assert np.abs(live_pose[:3, 3] - truth[:3, 3]).max() < 3e-3
        cos = (np.trace(live_pose[:3, :3].T @ truth[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(min(cos, 1.0))) < 0.5
    # the composites: bitwise sequence's frames, and not the input (the bunny is there)
    for i in range(4):
        live = read_ldr(rec / f"frame_{i:06d}.png")
        seq = read_ldr(seq_out / "frames" / f"{i:06d}.png")
        assert live.dtype == seq.dtype == np.uint8
        assert np.array_equal(live, seq), f"frame {i}: {np.abs(live.astype(int) - seq).max()}"
        inp = read_ldr(clip.frames / f"f{i}.png")
        assert np.mean(np.any(live != inp, axis=2)) > 0.02
