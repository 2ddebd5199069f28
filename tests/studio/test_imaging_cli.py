"""What the page shows (display of each layer, encoding) and the command's bad input."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from arlight.demo import DEMO_DIR
from arlight.studio import imaging


@pytest.fixture(scope="module")
def demo():
    from arlight.scene.load import load_scene

    return load_scene(DEMO_DIR / "scene.toml")


def test_composite_without_change_shows_the_frame_codes_exactly(demo):
    codes = imaging.display("composite", {"composite": demo.frame}, demo.camera.transfer,
                            0.0, None)
    assert np.array_equal(codes, demo.frame_codes)
    brighter = imaging.display("composite", {"composite": demo.frame},
                               demo.camera.transfer, 1.0, None)
    assert np.array_equal(brighter, demo.camera.transfer.__class__(
        demo.camera.transfer.kind, demo.camera.transfer.gamma,
        demo.camera.transfer.exposure + 1.0).to_display(demo.frame))


def test_delta_mask_and_error_layers(demo):
    tr = demo.camera.transfer
    delta = np.zeros((2, 3, 3), np.float32)
    delta[0, 0] = -0.2
    delta[1, 2] = 0.2
    d = imaging.display("delta", {"delta": delta}, tr, 0.0, None)
    assert d[0, 1].tolist() == [128, 128, 128]  # no change: mid-grey
    assert (d[0, 0] < 128).all() and (d[1, 2] > 128).all()
    assert (d[0, 0].astype(int) + d[1, 2] == 255).all()  # symmetric about mid-grey
    m = imaging.display("mask", {"mask": np.array([[0.0, 1.0]], np.float32)}, tr, 0, None)
    assert m.tolist() == [[[0, 0, 0], [255, 255, 255]]]
    comp = np.full((2, 2, 3), 0.3, np.float32)
    gt = comp.copy()
    assert not imaging.display("error", {"composite": comp}, tr, 0, gt).any()
    gt[0, 0] += 0.05
    e = imaging.display("error", {"composite": comp}, tr, 0, gt)
    assert np.array_equal(e[0, 0], tr.to_display(np.full(3, imaging.ERROR_GAIN * 0.05,
                                                         np.float32)))
    assert not imaging.display("error", {"composite": comp}, tr, 0, None).any()


def test_png_frames_are_lossless_and_jpeg_close(demo):
    codes = demo.frame_codes
    png = np.asarray(Image.open(io.BytesIO(imaging.encode(codes, "png"))))
    assert np.array_equal(png, codes)
    jpg = np.asarray(Image.open(io.BytesIO(imaging.encode(codes, "jpeg", 90))), float)
    assert np.abs(jpg - codes).mean() < 3


def test_ground_truth_is_box_filtered_and_adds_the_error_layer(tmp_path, demo):
    from arlight.io.images import write_exr
    from arlight.studio import Engine, StudioConfig

    gt = tmp_path / "gt.exr"
    write_exr(gt, demo.frame)
    eng = Engine(StudioConfig(DEMO_DIR / "scene.toml", resolution=(160, 120),
                              ground_truth=gt))
    assert eng.ground_truth.shape == (120, 160, 3)
    np.testing.assert_allclose(eng.ground_truth, eng.scene.frame, rtol=1e-5, atol=1e-7)
    assert "error" in eng.info()["layers"]


@pytest.mark.parametrize("args, needle", [
    (["missing.toml"], "not found"),
    ([str(DEMO_DIR / "scene.toml"), "--resolution", "100x100"], "--resolution"),
    ([str(DEMO_DIR / "scene.toml"), "--resolution", "big"], "--resolution"),
    ([str(DEMO_DIR / "scene.toml"), "--format", "gif"], "--format"),
    ([str(DEMO_DIR / "scene.toml"), "--method", "reference"], "not interactive"),
    ([str(DEMO_DIR / "scene.toml"), "--method", "nope"], "unknown method"),
    ([str(DEMO_DIR / "world.toml")], "frame"),
])
def test_bad_input_exits_2_before_serving(args, needle, capsys):
    from arlight.cli import main

    assert main(["studio", *args, "--port", "0"]) == 2
    assert needle in capsys.readouterr().err
