"""End to end: real slambook2 frames -> light -> composite; the suite scene with depth."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from arlight.methods import RenderSettings, get_method
from arlight.probeless.compose import ar_scene, place_on_surface, virtual_sphere
from arlight.probeless.reconstruct import reconstruct
from arlight.probeless.rgbd_io import read_sequence

SLAMBOOK = Path(str(resources.files("arlight") / "data" / "rgbd" / "slambook2_small"))


def test_slambook_light_and_composite():
    """Real RGB-D keyframes: reconstruct, estimate (method ``probeless``, ART4), insert a
    virtual sphere on the table: the sphere is drawn and the frame away from it is untouched.
    (That real pixels only darken is guaranteed by E7's clamp, ``delta ≤ 0``, so it is not
    asserted.) Rejects a pipeline that fails on real, holey depth or that changes pixels the
    sphere cannot affect."""
    frames = read_sequence(SLAMBOOK, SLAMBOOK / "pose.txt")
    mesh = reconstruct(frames, volume=6.0, resolution=160, depth_trunc=5.0)
    f = frames[0]
    p, n = place_on_surface(mesh, f, (0.66 * 160, 0.55 * 120), up=np.array([0, -1.0, 0]),
                            search=20)
    from arlight.light.estimate import LightEstimate

    scene = ar_scene(f, mesh, [virtual_sphere(p + 0.08 * n, 0.08)], LightEstimate())
    layers = get_method("probeless")(scene, RenderSettings(options={"variant": "ART4"}))
    virt = layers.mask > 0
    assert virt.sum() > 10 and np.all(layers.composite[virt] >= 0)
    far = ~virt & np.all(layers.delta == 0, axis=-1)
    assert np.array_equal(layers.composite[far], f.colour[far])
    assert layers.stats["light_rank"] >= 4


def test_eval_suite_scene_with_depth(tmp_path):
    """``probeless`` in ``arlight eval`` on bunny-box (the suite scene whose proxy carries
    depth): the cell runs, and the estimated dominant direction points at the lamp above and
    in front of the box (dot > 0.9). Rejects a method that is skipped, fails, or estimates
    the light from the wrong side."""
    import json

    from arlight.cli import main

    out = tmp_path / "r"
    assert main(["eval", "--quick", "--scenes", "bunny-box", "-m", "probeless", "--repeats",
                 "1", "--sweep", "", "-o", str(out)]) == 0
    cell = json.loads((out / "results.json").read_text())["cells"][0]
    assert not cell.get("skipped") and not cell.get("error")
    d = np.array([cell["stats"][f"light_dir_{a}"] for a in "xyz"])
    lamp = np.array([0.05, 0.9, 0.35]) - np.array([0.0, 0.09, 0.0])
    assert d @ lamp / np.linalg.norm(lamp) > 0.9
