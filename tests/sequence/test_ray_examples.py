"""The documented ``--ray auto`` examples (docs/sequence.md) end to end on a local Ray, and
their results equal to the sequential run's (issue #32, part 5).

The scene (:func:`tests.conftest.area_light_scene`) is also lit by an environment map: its
radiance map is part of the world that Ray's object store hands to every worker as a
*read-only* array, which ``mitsuba.Bitmap`` refused ("internal error (TypeError at
distributed.py:143)"); the test scenes of ``test_ray.py`` have no environment map, so
nothing ran that path. Layers (``--layers``) come back to the driver read-only too and are
written as EXR there.

What is compared: the frames' PNG bytes, the decoded float32 EXR layers (with
``--layers``) and the MP4 bytes (bitexact encoder) — bitwise, because every method here is
deterministic for a fixed seed (the sequence uses the same seed in every frame and in every
process), so any difference is a bug, not noise.

Rejects: a read-only world or layer reaching ``mitsuba.Bitmap`` (the run fails); a Ray task
that renders another frame's pose, object transform or seed than the sequential loop (wrong
frame indices on Ray, a per-worker seed); results written in completion order under the
wrong index.

Ray's start-up takes ~6 s on 2 shared cores and each run here ~15–40 s: the fast tier keeps
the issue's own command (image folder, ``--poses scene``, dlpv) plus a Ray-free check of the
read-only world; the other documented examples are ``slow``.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from arlight.io.images import read_hdr, read_ldr
from tests.conftest import area_light_scene
from tests.sequence.conftest import Tiny, cli, make_tiny, run_cli

N_FRAMES = 3


def env_scene() -> dict:
    """The small test room with its area light and the demo's environment map."""
    from arlight.demo import DEMO_DIR

    d = area_light_scene(32, 24)
    d["lights"].append({"type": "envmap", "file": str(DEMO_DIR / "lebombo_512x256.hdr"),
                        "scale": 0.5})
    return d


@pytest.fixture(scope="module")
def env_tiny(tmp_path_factory) -> Tiny:
    """Three 32×24 frames of :func:`env_scene` (PNG folder), an orbiting camera's poses
    file and the ball's keyframes."""
    return make_tiny(tmp_path_factory.mktemp("env"), n=N_FRAMES, scene=env_scene())


@pytest.fixture(scope="module")
def env_clip(env_tiny) -> Path:
    from arlight.sequence.video import encode

    return encode(env_tiny.folder / "clip.mp4",
                  [read_ldr(f) for f in sorted(env_tiny.frames.iterdir())], fps=12)


@pytest.fixture(scope="module")
def turntable(env_tiny) -> Path:
    """The docs' turntable keyframes TOML for the ball (first and last frame)."""
    p = env_tiny.folder / "turntable.toml"
    p.write_text(f"[[objects.ball]]\nframe = 0\ntransform = {{ rotate = [0, 1, 0, 0] }}\n"
                 f"[[objects.ball]]\nframe = {N_FRAMES - 1}\n"
                 "transform = { rotate = [0, 1, 0, 40], translate = [0.1, 0, 0] }\n")
    return p


def _outputs(out: Path) -> dict[str, object]:
    """Frame PNG bytes, decoded EXR layers and the MP4 bytes of a sequence folder."""
    got: dict[str, object] = {p.relative_to(out).as_posix(): p.read_bytes()
                              for p in sorted((out / "frames").glob("*.png"))}
    for p in sorted((out / "layers").glob("*/*.exr")):
        got[p.relative_to(out).as_posix()] = read_hdr(p)
    got["sequence.mp4"] = (out / "sequence.mp4").read_bytes()
    return got


def _assert_ray_equals_sequential(tmp_path: Path, args: list[str]) -> dict:
    """Run ``arlight ARGS`` sequentially (in this process) and on a local Ray with two
    workers (a fresh process, as a user runs it); every output equal. Returns the Ray run's
    summary."""
    import json

    seq, ray_out = tmp_path / "seq", tmp_path / "ray"
    rc, _, err = cli([*args, "-o", str(seq)])
    assert rc == 0, err
    r = run_cli([*args, "-o", str(ray_out), "--ray", "auto", "--workers", "2"])
    assert r.returncode == 0, r.stderr
    a, b = _outputs(seq), _outputs(ray_out)
    assert a.keys() == b.keys() and len([k for k in a if k.startswith("frames/")]) == N_FRAMES
    for k in a:
        if isinstance(a[k], np.ndarray):
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
        else:
            assert a[k] == b[k], k
    summary = json.loads((ray_out / "summary.json").read_text())
    assert summary["backend"] == "ray (auto)" and summary["rendered"] == N_FRAMES
    return summary


def _base(t: Tiny, frames: Path, poses: str, method: str, *extra: str) -> list[str]:
    return ["sequence", str(t.scene), "--frames", str(frames), "--poses", poses, "-m", method,
            *extra]


def test_folder_poses_scene_dlpv_on_ray_equals_sequential(env_tiny, tmp_path):
    """The issue's command: a folder of PNG frames, ``--poses scene``, dlpv (with layers,
    which the driver writes from Ray's read-only results)."""
    _assert_ray_equals_sequential(tmp_path, _base(env_tiny, env_tiny.frames, "scene", "dlpv",
                                                  "--layers"))


def test_world_unpickled_read_only_renders_like_the_original(env_tiny):
    """Without Ray: the job pickled as Ray does (protocol 5, out-of-band buffers), its arrays
    handed back read-only, renders the same frame bitwise. Rejects any ``mitsuba.Bitmap``
    (or in-place write) on a world array that assumes it is writable."""
    from arlight.methods import RenderSettings
    from arlight.scene.load import load_scene
    from arlight.sequence.build import build_job
    from arlight.sequence.frames import FrameSource
    from arlight.sequence.job import _PREPARED, render_frame

    source = FrameSource(env_tiny.frames)
    job = build_job(load_scene(env_tiny.scene), source, "dlpv", RenderSettings(spp=1),
                    poses="scene")
    buffers: list[pickle.PickleBuffer] = []
    data = pickle.dumps(job, protocol=5, buffer_callback=buffers.append)
    ro = pickle.loads(data, buffers=[memoryview(b.raw()).toreadonly() for b in buffers])
    env = next(lt.radiance_map for lt in ro.world.lights if lt.type == "envmap")
    assert env is not None and not env.flags.writeable  # the case Ray produces
    frame = next(iter(source))
    _PREPARED.clear()
    want = render_frame(job, frame).display
    _PREPARED.clear()  # prepare again, from the read-only world
    got = render_frame(ro, frame).display
    _PREPARED.clear()
    np.testing.assert_array_equal(got, want)


@pytest.mark.slow
def test_video_poses_file_reference_on_ray_equals_sequential(env_tiny, env_clip, tmp_path):
    """A video and a poses file with the path tracer (``reference``, the docs' Ray example)
    and the ball's object motion."""
    _assert_ray_equals_sequential(tmp_path, _base(
        env_tiny, env_clip, str(env_tiny.poses), "reference", "--spp", "4", "--objects",
        str(env_tiny.objects)))


@pytest.mark.slow
def test_folder_poses_file_reference_on_ray_equals_sequential(env_tiny, tmp_path):
    """The docs' ``--frames DIR --poses poses.txt -m reference --ray auto`` example."""
    _assert_ray_equals_sequential(tmp_path, _base(env_tiny, env_tiny.frames,
                                                  str(env_tiny.poses), "reference", "--spp",
                                                  "4"))


@pytest.mark.slow
def test_video_poses_scene_dlpv_on_ray_equals_sequential(env_tiny, env_clip, tmp_path):
    _assert_ray_equals_sequential(tmp_path, _base(env_tiny, env_clip, "scene", "dlpv"))


@pytest.mark.slow
def test_folder_poses_scene_turntable_ibl_on_ray_equals_sequential(env_tiny, turntable,
                                                                   tmp_path):
    """The docs' turntable example: ``--poses scene --objects turntable.toml -m ibl``."""
    _assert_ray_equals_sequential(tmp_path, _base(env_tiny, env_tiny.frames, "scene", "ibl",
                                                  "--objects", str(turntable)))
