"""A tiny sequence on disk: scene file, frames, camera poses and an object's motion."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from arlight.io.images import write_png
from arlight.scene.load import parse_scene
from arlight.sequence.poses import write_poses
from arlight.sequence.synthetic_video import object_path, orbit_poses
from tests.conftest import area_light_scene

ARLIGHT = shutil.which("arlight", path=str(Path(sys.executable).parent))


@dataclass
class Tiny:
    folder: Path
    scene: Path
    frames: Path
    poses: Path
    objects: Path
    n: int

    def args(self, out: Path, *extra: str, method: str = "reference") -> list[str]:
        return ["sequence", str(self.scene), "--frames", str(self.frames), "--poses",
                str(self.poses), "--objects", str(self.objects), "-m", method, "--spp", "4",
                "-o", str(out), *extra]


def make_tiny(folder: Path, n: int = 8, width: int = 32, height: int = 24,
              virtual: bool = True, scene: dict | None = None) -> Tiny:
    """``n`` frames of ``width``×``height`` in ``folder``: the scene (``scene``, a scene dict
    with a virtual shape ``ball`` when ``virtual``; default: :func:`area_light_scene`), PNG
    frames, an orbiting camera's poses file and the ball's keyframed motion."""
    folder.mkdir(parents=True, exist_ok=True)
    d = scene if scene is not None else area_light_scene(width, height, virtual=virtual)
    scene = folder / "scene.json"
    scene.write_text(json.dumps(d))
    sc = parse_scene(d)
    poses = write_poses(folder / "poses.txt",
                        orbit_poses(sc.camera.world_from_camera, [0, 0.25, 0], n, 20))
    frames = folder / "frames"
    frames.mkdir(exist_ok=True)
    ramp = np.linspace(40, 200, width, dtype=np.float64)[None, :, None]
    for i in range(n):  # a horizontal ramp that brightens over time (natural name order)
        img = np.broadcast_to(ramp + 3 * i, (height, width, 3))
        write_png(frames / f"f{i}.png", np.clip(img, 0, 255).astype(np.uint8))
    objects = folder / "objects.txt"
    lines = []
    if virtual:
        ball = next(s for s in sc.shapes if s.name == "ball")
        from arlight.sequence.poses import matrix_to_quat

        path = object_path(ball.to_world, n, (0.2, 0.0, 0.0), 40.0)
        for i in (0, n // 2, n - 1):  # keyframes
            m = path[i]
            q = matrix_to_quat(m[:3, :3])
            lines.append(f"{i} ball " + " ".join(repr(float(x)) for x in (*m[:3, 3], *q)))
    objects.write_text("\n".join(lines) + "\n")
    return Tiny(folder, scene, frames, poses, objects, n)


@pytest.fixture(scope="session")
def tiny(tmp_path_factory) -> Tiny:
    return make_tiny(tmp_path_factory.mktemp("tiny"))


@pytest.fixture(scope="session")
def full_run(tiny, tmp_path_factory) -> Path:
    """An uninterrupted sequential run of ``tiny`` with layers (the reference run)."""
    out = tmp_path_factory.mktemp("full") / "out"
    rc, _, err = cli(tiny.args(out, "--layers"))
    assert rc == 0, err
    return out


def run_cli(args: list[str], env: dict | None = None, timeout: float = 300
            ) -> subprocess.CompletedProcess:
    e = {**os.environ, "PYTHONFAULTHANDLER": "1", **(env or {})}
    return subprocess.run([ARLIGHT, *args], capture_output=True, text=True, env=e,
                          timeout=timeout)


def cli(args: list[str]) -> tuple[int, str, str]:
    """``arlight ARGS`` in this process (faster than a subprocess): exit code, out, err."""
    import contextlib
    import io

    from arlight.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, out.getvalue(), err.getvalue()
