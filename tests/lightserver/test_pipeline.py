"""The server's pipeline producer (issue 17's NearFieldServer) behind the transport."""

from __future__ import annotations

import os

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.lightserver import LightClient, LightServer
from arlight.lightserver.pipeline import (
    FolderFrames,
    MovingLightFrames,
    default_rig,
    pipeline_producer,
    write_frames,
)
from arlight.scene.load import load_scene

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENE = os.path.join(ROOT, "src/arlight/data/scenes/cornell-near-field/proxy.toml")


def _f32(a):
    return np.asarray(a).astype(np.float32).astype(np.float64)


def test_folder_frames_through_the_pipeline_reach_the_client(tmp_path):
    """Two recorded frames (a bright patch that moves) → NearFieldServer → wire → client:
    the client's state is the pipeline's last output to packing precision."""
    world = load_scene(SCENE).world
    rig = default_rig(world, size=16)

    def frames(i):
        imgs = []
        for k in range(len(rig)):
            img = np.full((16, 16, 3), 0.2, np.float32)
            img[4 + i:7 + i, 5:8] = 40.0 if k == 2 else 0.2  # a lamp seen by one camera
            imgs.append(img)
        return imgs

    write_frames(frames, rig, tmp_path / "frames", 2)
    producer = pipeline_producer(__import__("pathlib").Path(SCENE), tmp_path / "frames",
                                 vals=4, camera_size=16, atlas=64)
    with LightServer(producer, bind="tcp://127.0.0.1:*", rate_hz=50, count=3) as server:
        with LightClient(*server.endpoints) as client:
            assert server.wait(60)
            got = client.wait_for(3, timeout=20)
    want = producer.server.light
    assert got.count == want.count == 4 and got.n_objects == len(world.virtual_shapes) == 1
    np.testing.assert_array_equal(got.positions, _f32(want.positions))
    np.testing.assert_array_equal(got.intensity, _f32(want.intensity))
    np.testing.assert_array_equal(got.sh, _f32(want.sh))
    ang = np.degrees(np.arccos(np.clip((got.normals * want.normals).sum(1), -1, 1)))
    assert ang.max() < 0.5


def test_folder_frames_errors(tmp_path):
    with pytest.raises(InputError, match="not a folder"):
        FolderFrames(tmp_path / "missing", ["a"])
    (tmp_path / "f" / "0001").mkdir(parents=True)
    with pytest.raises(InputError, match="no image for camera 'a'"):
        FolderFrames(tmp_path / "f", ["a"])


def test_moving_light_moves_the_first_area_light():
    world = load_scene(SCENE).world
    src = MovingLightFrames(world, default_rig(world, 8), radius=0.3, loop=4)
    p = [np.asarray(src.world_at(k).lights[0].params["to_world"])[:3, 3] for k in range(5)]
    assert np.allclose(p[0], p[4]) and not np.allclose(p[0], p[1])
    assert np.isclose(np.linalg.norm(p[1] - p[3]), 0.6)  # opposite points of the circle
    assert all(np.isclose(q[1], p[0][1]) for q in p)  # stays in the ceiling's plane


def test_serve_light_pipeline_from_a_folder_and_bad_folder(tmp_path, capsys):
    from arlight.cli import main

    world = load_scene(SCENE).world
    rig = default_rig(world, size=16)
    write_frames(lambda i: [np.full((16, 16, 3), 1.0 + i, np.float32)] * len(rig), rig,
                 tmp_path / "frames", 1)
    base = ["serve-light", "--source", "pipeline", "--world", SCENE, "--camera-size", "16",
            "--atlas", "64", "--vals", "4", "--bind", "tcp://127.0.0.1:*", "--count", "2"]
    assert main([*base, "--frames", str(tmp_path / "frames")]) == 0
    assert f"published 2 updates ({48 + 32 * 4 + 108} B each)" in capsys.readouterr().err
    assert main([*base, "--frames", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--frames" in err[0] and "nothing" in err[0]
