"""Rendering frames of a job: state kept across frames, fixed random sequences, identities.

Rejects: preparing the world again for every frame (the state must be kept; only ``pose``
runs per frame); deriving a new seed per frame when the job does not ask for it (Kán's
fixed per-frame random sequence: a static input renders bitwise identically); a sequence
frame that differs from the one-shot render of the same world and view; a composite that
changes the frame where there is no virtual object.
"""

from __future__ import annotations

import numpy as np
import pytest

from arlight.evaluate.metrics import temporal_flicker
from arlight.methods import (
    BaseMethod,
    Capabilities,
    MethodSpec,
    RenderSettings,
    get_method,
    register,
    unregister,
)
from arlight.scene.load import load_scene
from arlight.scene.model import ARScene
from arlight.sequence.build import build_job
from arlight.sequence.frames import FrameSource, InputFrame
from arlight.sequence.job import _PREPARED, SequenceJob, render_frame
from tests.sequence.conftest import make_tiny


def _job(tiny, method="reference", **kw) -> tuple[SequenceJob, FrameSource]:
    src = FrameSource(tiny.frames)
    job = build_job(load_scene(tiny.scene), src, method, RenderSettings(spp=4, seed=7),
                    poses=tiny.poses, objects=tiny.objects, **kw)
    return job, src


def test_frame_equals_the_one_shot_render_of_its_view(tiny):
    job, src = _job(tiny)
    fr = list(src)[5]
    res = render_frame(job, fr)
    view = job.view(fr)
    assert view.object_transforms and not np.array_equal(view.camera.world_from_camera,
                                                         job.camera.world_from_camera)
    one_shot = get_method("reference")(ARScene.compose(job.world, view),
                                       RenderSettings(spp=4, seed=7))
    codes = view.camera.transfer.to_display(one_shot.composite)
    assert np.array_equal(res.display, codes)


def test_render_scale_renders_the_small_view_and_composites_over_the_full_frame(tiny):
    """``render_scale = 2``: the frame is the method's render of the view box-filtered to
    half size (camera intrinsics halved), its layers upsampled and composited over the
    *full-size* frame. Rejects rendering the full-size view anyway, compositing over the
    upsampled small frame (the photograph blurred where nothing changed), and the scale
    left out of the job's identity (a resumed run would mix scales)."""
    from arlight.errors import InputError
    from arlight.layers import composite, upsample

    job, src = _job(tiny, render_scale=2)
    fr = list(src)[3]
    res = render_frame(job, fr)
    full = job.view(fr)
    small = get_method("reference").render(
        get_method("reference").prepare(job.world, RenderSettings(spp=4, seed=7)),
        full.resized(16, 12), RenderSettings(spp=4, seed=7))
    m, d, k = (upsample(a, 24, 32) for a in (small.mixed, small.delta, small.mask))
    want = full.camera.transfer.to_display(composite(full.frame, m, d, k).astype(np.float32))
    assert np.array_equal(res.display, want)
    untouched = (k == 0) & np.all(d == 0, axis=2)
    assert untouched.any() and np.array_equal(res.display[untouched], fr.codes[untouched])
    assert job.key != _job(tiny)[0].key
    with pytest.raises(InputError, match="render-scale"):
        _job(tiny, render_scale=5)


class _Counting(BaseMethod):
    """A method that counts its hooks (its frames are the input frame)."""

    spec = MethodSpec(name="counting-seq", description="counts prepare/pose/render",
                      capabilities=Capabilities(interactive=True))
    calls: dict[str, int] = {}

    def prepare_world(self, world, options, settings):
        self.calls["prepare"] = self.calls.get("prepare", 0) + 1
        return world

    def pose(self, state, transforms, settings):
        self.calls["pose"] = self.calls.get("pose", 0) + 1
        return state.data

    def render_view(self, data, view, options, settings, timer):
        self.calls["render"] = self.calls.get("render", 0) + 1
        from arlight.methods import Layers

        z = np.zeros_like(view.frame)
        return Layers.assemble(view.frame, z, z, z[..., 0])


def test_prepared_once_per_job_and_posed_per_frame(tiny):
    register(_Counting)
    try:
        _Counting.calls.clear()
        _PREPARED.clear()
        job, src = _job(tiny, method="counting-seq")
        for fr in src:
            render_frame(job, fr)
        assert _Counting.calls == {"prepare": 1, "pose": tiny.n, "render": tiny.n}
        res = render_frame(job, next(iter(src)))
        assert res.stats["prepare_seconds"] == 0.0 and _Counting.calls["prepare"] == 1
    finally:
        unregister("counting-seq")
        _PREPARED.clear()


def test_fixed_random_sequence_per_frame_no_noise_flicker(tmp_path):
    """A static input (same pose, same frame every frame): with the fixed seed the frames
    are bitwise identical (flicker exactly 0); with a seed per frame they are not."""
    t = make_tiny(tmp_path, n=3)
    src = FrameSource(t.frames)
    frame = next(iter(src))
    frames = [InputFrame(i, "same", codes=frame.codes) for i in range(3)]
    sc = load_scene(t.scene)
    comps = {}
    for vary in (False, True):
        job = build_job(sc, src, "reference", RenderSettings(spp=4), poses="scene",
                        vary_seed=vary)
        comps[vary] = [render_frame(job, f, None).display.astype(float) for f in frames]
    assert temporal_flicker(comps[False]) == 0.0
    assert temporal_flicker(comps[True]) > 0.1  # code values


def test_no_virtual_object_returns_the_frames_unchanged(tmp_path):
    t = make_tiny(tmp_path, n=3, virtual=False)
    src = FrameSource(t.frames)
    job = build_job(load_scene(t.scene), src, "reference", RenderSettings(spp=4),
                    poses=t.poses)
    for fr in src:
        assert np.array_equal(render_frame(job, fr).display, fr.codes)


def test_job_key_changes_with_every_input(tiny):
    job, _ = _job(tiny)
    base = job.parts
    other, _ = _job(tiny, vary_seed=True)
    assert [k for k in base if base[k] != other.parts[k]] == ["settings"]
    other = SequenceJob(**{**job.__dict__, "poses": [p + 0 for p in job.poses[:-1]]
                           + [job.poses[0]], "parts": {}})
    assert [k for k in base if base[k] != other.parts[k]] == ["poses"]


def test_job_key_tells_which_frame_an_object_motion_belongs_to(tiny):
    """The former hasher flattened the per-frame object transforms into one list of
    (name, matrix) items, so a motion at frame 0 and the same motion at frame 1 gave the
    same key (and a resumed run would keep frames rendered for the other input)."""
    job, _ = _job(tiny)
    m = np.eye(4)
    m[0, 3] = 0.5
    empty = [{} for _ in job.poses]
    first = SequenceJob(**{**job.__dict__, "objects": [{"ball": m}, *empty[1:]],
                           "parts": {}})
    second = SequenceJob(**{**job.__dict__, "objects": [{}, {"ball": m}, *empty[2:]],
                            "parts": {}})
    assert first.parts["objects"] != second.parts["objects"]
    assert first.key != second.key


@pytest.mark.parametrize("method", ["dlpv", pytest.param("ibl", marks=pytest.mark.slow)])
def test_interactive_methods_render_a_sequence(tiny, method):
    job, src = _job(tiny, method=method)
    res = [render_frame(job, fr) for fr in list(src)[:2]]
    assert [r.stats["prepare_seconds"] > 0 for r in res] == [True, False]
    assert all(r.display.shape == (24, 32, 3) for r in res)


def test_split_frame_is_the_sample_weighted_mean_of_its_parts(tiny):
    """``split = 3`` of 5 spp: parts of 2, 2 and 1 samples with seeds frame_seed(s, k);
    the frame is their composites' mean weighted 2:2:1, whatever order they arrive in."""
    from arlight.progressive import frame_seed
    from arlight.sequence.job import merge_parts

    src = FrameSource(tiny.frames)
    job = build_job(load_scene(tiny.scene), src, "reference", RenderSettings(spp=5, seed=7),
                    poses=tiny.poses, objects=tiny.objects, split=3)
    fr = list(src)[2]
    parts = [render_frame(job, fr, None, k) for k in range(3)]
    merged = merge_parts(job, parts[::-1])
    view = job.view(fr)
    method = get_method("reference")
    comps = [method(ARScene.compose(job.world, view),
                    RenderSettings(spp=n, seed=frame_seed(7, k))).composite
             for k, n in enumerate((2, 2, 1))]
    mean = (0.4 * comps[0].astype(np.float64) + 0.4 * comps[1] + 0.2 * comps[2])
    assert np.array_equal(merged.display, view.camera.transfer.to_display(
        mean.astype(np.float32)))
    assert merged.stats["parts"] == 3 and merged.layers == {}
    with pytest.raises(Exception, match="progressive"):
        build_job(load_scene(tiny.scene), src, "dlpv", RenderSettings(spp=4),
                  poses=tiny.poses, split=2)
