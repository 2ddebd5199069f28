"""TSDF reconstruction, the RGB-D reader and ``arlight light probeless`` (bad input too)."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest

from arlight.errors import InputError
from arlight.light.estimate import LightEstimate
from arlight.probeless import synthetic_rgbd as S
from arlight.probeless.reconstruct import reconstruct
from arlight.probeless.rgbd_io import read_sequence
from tests.cli_invoke import MainRunner

SLAMBOOK = Path(str(resources.files("arlight") / "data" / "rgbd" / "slambook2_small"))


@pytest.fixture(scope="module")
def frames():
    return [f.rgbd for f in S.render_sequence("sh", n=3, moving=True, width=64, height=48,
                                              spp=8)]


def _write_dir(folder: Path, frames, poses: bool = True) -> Path:
    """An RGB-D folder: 8-bit sRGB colour, 16-bit millimetre depth, a Redwood .log."""
    (folder / "color").mkdir(parents=True)
    (folder / "depth").mkdir()
    lines = []
    for i, f in enumerate(frames):
        srgb = np.clip(f.colour, 0, 1) ** (1 / 2.2)
        cv2.imwrite(str(folder / "color" / f"{i:03d}.png"),
                    (srgb[..., ::-1] * 255).astype(np.uint8))
        cv2.imwrite(str(folder / "depth" / f"{i:03d}.png"),
                    np.round(f.depth * 1000).astype(np.uint16))
        lines.append(f"{i} {i} {i + 1}")
        lines += [" ".join(f"{v:.9f}" for v in row) for row in f.camera.world_from_camera]
    if poses:
        (folder / "traj.log").write_text("\n".join(lines) + "\n")
    c = frames[0].camera
    (folder / "intrinsics.json").write_text(json.dumps({"fx": c.fx, "fy": c.fy, "cx": c.cx,
                                                        "cy": c.cy}))
    return folder


def test_tsdf_mesh_matches_the_modelled_floor(frames):
    """The Open3D TSDF mesh of the synthetic frames puts the floor at y = 0 within a voxel
    and a half. Rejects passing the pose instead of its inverse as Open3D's extrinsic."""
    mesh = reconstruct(frames)
    v = mesh.mesh.vertices.astype(np.float64)
    n = mesh.mesh.normals
    floor = v[(np.abs(n[:, 1]) > 0.95) & (np.abs(v[:, 0]) < 0.5) & (v[:, 1] < 0.02)]
    assert len(floor) > 50
    assert abs(np.median(floor[:, 1])) < 1.5 * 2.0 / 268
    assert mesh.role == "real" and mesh.type == "mesh"


def test_cli_end_to_end_on_slambook_frames(tmp_path):
    """Real frames: the command writes a LightEstimate (16 SH, confidence) and the per-frame
    file; the light loads back. Rejects a command that writes nothing or an unreadable
    estimate."""
    from arlight.cli import app

    out = tmp_path / "light.json"
    r = MainRunner().invoke(app, ["light", "probeless", str(SLAMBOOK), "--poses",
                                 str(SLAMBOOK / "pose.txt"), "--volume", "6", "--resolution",
                                 "160", "-o", str(out)])
    assert r.exit_code == 0, r.output
    est = LightEstimate.load(out)
    assert est.sh.shape == (16, 3) and 0 < est.confidence <= 1
    doc = json.loads((tmp_path / "light.frames.json").read_text())
    assert len(doc["frames"]) == 5 and all(f["rank"] >= 1 for f in doc["frames"])
    # a scene uses the estimate through an `sh` light
    from arlight.scene.load import parse_scene

    raw = json.loads(out.read_text())
    scene = parse_scene({"camera": {"resolution": [8, 6], "fov_y_deg": 40,
                                    "look_at": {"origin": [0, 1, 2], "target": [0, 0, 0]}},
                         "shapes": [], "lights": [{"type": "sh", "coefficients":
                                                   raw["sh"]["coefficients"]}]})
    assert scene.lights[0].type == "sh" and len(scene.lights[0].params["coefficients"]) == 16


@pytest.mark.parametrize("case", ["size", "poses", "nodepth", "plane"])
def test_bad_input_exit_2_nothing_written(tmp_path, frames, case):
    """Colour and depth of different sizes, missing poses, a frame with no valid depth and
    a single plane (ill-conditioned light) each exit with status 2, one line naming the
    file/field, and write nothing. Rejects a traceback, a partial output or a garbage
    light."""
    from arlight.cli import app

    folder = _write_dir(tmp_path / "seq", frames, poses=case != "poses")
    args = ["light", "probeless", str(folder), "-o", str(tmp_path / "light.json")]
    if case != "poses":
        args += ["--poses", str(folder / "traj.log")]
    expect = {"size": "depth", "poses": "--poses", "nodepth": "no valid depth",
              "plane": "undetermined"}[case]
    if case == "size":
        d = cv2.imread(str(folder / "depth" / "001.png"), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(folder / "depth" / "001.png"), d[:-2])
    elif case == "nodepth":
        cv2.imwrite(str(folder / "depth" / "002.png"), np.zeros((48, 64), np.uint16))
    elif case == "plane":  # a static camera in front of a flat wall
        for p in (folder / "depth").iterdir():
            cv2.imwrite(str(p), np.full((48, 64), 800, np.uint16))
        lines = (folder / "traj.log").read_text().splitlines()
        (folder / "traj.log").write_text("\n".join(
            ln if i % 5 == 0 else lines[i % 5] for i, ln in enumerate(lines)) + "\n")
    r = MainRunner().invoke(app, args)
    assert r.exit_code == 2, r.output
    assert expect in r.output and "Traceback" not in r.output
    assert not (tmp_path / "light.json").exists()
    assert not (tmp_path / "light.frames.json").exists()


def test_reader_names_file_and_field(tmp_path, frames):
    """The reader's errors are InputErrors naming the file and field (fewer poses than
    frames)."""
    folder = _write_dir(tmp_path / "seq", frames)
    log = folder / "traj.log"
    log.write_text("\n".join(log.read_text().splitlines()[:5]) + "\n")
    with pytest.raises(InputError) as exc:
        read_sequence(folder, log)
    assert exc.value.field == "poses" and "traj.log" in str(exc.value)


def test_raw_sensor_depth_is_scaled_and_must_be_one_channel(tmp_path):
    """A 16-bit PNG of sensor units is read unconverted and divided by the units per metre
    (1500 mm → 1.5 m); a three-channel image given as depth is an error naming the file.
    Rejects reading it through the colour path (normalised to [0, 1] or gamma-decoded) and
    taking one channel of a colour image as depth."""
    from arlight.io.images import read_depth

    depth = tmp_path / "d.png"
    cv2.imwrite(str(depth), np.full((4, 5), 1500, np.uint16))
    assert np.array_equal(read_depth(depth, 1000.0), np.full((4, 5), 1.5, np.float32))
    colour = tmp_path / "c.png"
    cv2.imwrite(str(colour), np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(InputError, match="one channel") as e:
        read_depth(colour, 1000.0)
    assert e.value.file == str(colour)
