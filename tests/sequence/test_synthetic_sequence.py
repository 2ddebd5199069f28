"""The synthetic sequence with per-frame ground truth, and the metrics the benchmark reports.

Rejects: ground truth rendered without the frame's camera pose or object motion (the mask
would not move); metrics that cannot tell a method from the bare frame; a flicker metric
that scores an exact sequence above 0.
"""

from __future__ import annotations

import numpy as np
import pytest

from arlight.methods import RenderSettings
from arlight.sequence.job import render_frame
from arlight.sequence.synthetic_video import (
    ground_truth_flicker_floor,
    sequence_job,
    sequence_metrics,
    synthetic_sequence,
)

pytestmark = pytest.mark.slow  # ~15 s: four ground-truth renders of the bunny-box world


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    return synthetic_sequence(n_frames=4, width=32, spp=8, batches=4, depth=False,
                              cache_dir=tmp_path_factory.mktemp("cache"))


def test_ground_truth_follows_camera_and_object(seq):
    assert seq.count == 4 and seq.frames[0].shape == (24, 32, 3)
    m0, m3 = seq.masks[0], seq.masks[3]
    assert m0.sum() > 5 and m3.sum() > 5
    assert np.abs(m0 - m3).sum() > 2  # the bunny (and the camera) moved
    poses = np.array(seq.poses)
    assert not np.allclose(poses[0], poses[3])
    # the camera stays at its distance from the target on the orbit
    d = np.linalg.norm(poses[:, :3, 3] - poses[:, :3, 3].mean(0)[None], axis=1)
    assert d.max() < 0.2


def test_metrics_rank_a_method_above_the_bare_frame(seq):
    exact = sequence_metrics(seq.ground_truth, seq)
    assert exact["flicker"] == 0.0 and exact["psnr"] == 100.0
    bare = sequence_metrics(seq.frames, seq)
    job = sequence_job(seq, "reference", RenderSettings(spp=16))
    comps = []
    for fr in seq.input_frames():
        res = render_frame(job, fr)
        view = job.view(fr)
        comps.append(view.camera.transfer.to_radiance(res.display).astype(np.float32))
    ref = sequence_metrics(comps, seq)
    assert ref["psnr"] > bare["psnr"] + 1.0
    assert ground_truth_flicker_floor(seq) > 0
