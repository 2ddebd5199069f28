"""A small synthetic marker video, its calibration and scene, for the live tests."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from arlight.io.images import write_png
from arlight.live import marker_video as mv
from arlight.scene.save import to_toml

SIZE = (320, 240)
DIST = [0.02, 0.0, 0.0, 0.0, 0.0]
"""A small radial distortion the calibration claims (the frames have none): both paths must
undistort every frame and register with it, so forgetting it shows."""


@dataclass
class Clip:
    folder: Path
    frames: Path
    scene: Path
    calib: Path
    poses: list[np.ndarray]


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Clip:
    """Four frames of the orbit (PNG, lossless) at 320×240; the scene's own camera has other
    intrinsics than the calibration (70° vertical field of view), so using the scene's
    intrinsics instead of the calibration's shows."""
    root = tmp_path_factory.mktemp("live-clip")
    frames = root / "frames"
    frames.mkdir()
    tex = mv.table_texture()
    K = mv.intrinsics(SIZE)
    poses = mv.orbit(8)[:4]
    for i, p in enumerate(poses):
        write_png(frames / f"f{i}.png", mv.render_frame(tex, p, K, SIZE))
    calib = root / "calib.json"
    calib.write_text(json.dumps({"K": K.tolist(), "dist": DIST, "size": list(SIZE)}))
    model = Path(mv.__file__).resolve().parent.parent / "data" / "demo" / "bunny.ply"
    d = mv.scene_dict(str(model))
    d["camera"] = {"resolution": list(SIZE), "fov_y_deg": 70.0, "transfer": "srgb",
                   "world_from_camera": poses[0].tolist()}
    scene = root / "scene.toml"
    scene.write_text(to_toml(d))
    return Clip(root, frames, scene, calib, poses)


def plane_depth(pose: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Depth (m along +z) of the table plane Y = 0 seen from ``pose`` (OpenCV axes): per pixel
    the ray ``K⁻¹ (u, v, 1)`` meets the plane at ``t`` with ``(o + t·R d)_y = 0``."""
    w, h = size
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    ry = d @ pose[1, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -pose[1, 3] / ry
    return np.where(t > 0, t, 0.0).astype(np.float32)


@pytest.fixture(scope="module")
def clip_depth(clip) -> Path:
    """A folder of the clip's depth images (single-channel EXR), one per frame: the plane's
    depth, 0.3 m too far on the left half (a sensor disagreeing with the proxy there, so the
    light estimate that uses only agreeing samples depends on the depth given)."""
    from arlight.io.images import write_exr

    folder = clip.folder / "depth"
    folder.mkdir(exist_ok=True)
    K = mv.intrinsics(SIZE)
    for i, p in enumerate(clip.poses):
        d = plane_depth(p, K, SIZE)
        d[:, : SIZE[0] // 2] += 0.3
        write_exr(folder / f"d{i}.exr", d)
    return folder
