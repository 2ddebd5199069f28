"""The ``arlight light`` CLI: estimate / show, clear errors, no partial outputs."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from arlight.io.images import write_exr
from arlight.light.cli import app
from arlight.light.estimate import LightEstimate
from arlight.sphere.envmap import from_equirect
from tests.cli_invoke import MainRunner

runner = MainRunner()


@pytest.fixture
def probe_files(tmp_path, grace):
    eq = tmp_path / "grace.hdr.exr"
    write_exr(eq, grace)
    ang, _ = from_equirect(grace, "angular", 128)
    write_exr(tmp_path / "probe.exr", ang)
    return tmp_path


def test_estimate_equirect_and_show(probe_files):
    out = probe_files / "light.json"
    r = runner.invoke(app, ["estimate", str(probe_files / "grace.hdr.exr"), "--kind",
                            "equirect", "--lights", "8", "--sh-order", "3", "-o", str(out)])
    assert r.exit_code == 0, r.output
    est = LightEstimate.load(out)
    assert est.sh.shape == (16, 3) and len(est.lights) <= 7
    png = probe_files / "light.png"
    r = runner.invoke(app, ["show", str(out), "-o", str(png)])
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_estimate_probe_and_arcore_layout(probe_files):
    out = probe_files / "arcore.json"
    r = runner.invoke(app, ["estimate", str(probe_files / "probe.exr"), "--kind", "probe",
                            "--layout", "arcore", "-o", str(out)])
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert len(d["environmentalHdrAmbientSphericalHarmonics"]) == 27


def test_show_from_image(probe_files):
    png = probe_files / "direct.png"
    r = runner.invoke(app, ["show", str(probe_files / "grace.hdr.exr"), "-o", str(png),
                            "--lights", "4"])
    assert r.exit_code == 0, r.output
    assert png.stat().st_size > 1000


@pytest.mark.parametrize("args,needle", [
    (["estimate", "{d}/missing.hdr", "-o", "{d}/o.json"], "missing.hdr"),
    (["estimate", "{d}/probe.exr", "--kind", "equirect", "-o", "{d}/o.json"], "2:1"),
    (["estimate", "{d}/probe.exr", "--kind", "ball", "-o", "{d}/o.json"], "--ball-center"),
    (["estimate", "{d}/probe.exr", "--kind", "cube", "-o", "{d}/o.json"], "--kind"),
    (["estimate", "{d}/probe.exr", "--kind", "fisheye", "--fisheye-calib", "{d}/nope.yml",
      "-o", "{d}/o.json"], "nope.yml"),
    (["show", "{d}/bad.json", "-o", "{d}/o.png"], "bad.json"),
    (["estimate", "{d}/probe.exr", "--kind", "probe", "--layout", "webxr", "--sh-convention",
      "unity", "-o", "{d}/o.json"], "--sh-convention"),
    (["estimate", "{d}/probe.exr", "--kind", "ball", "--ball-center", "64,64",
      "--ball-radius", "60", "--ball-look", "1,0", "-o", "{d}/o.json"], "--ball-look"),
])
def test_bad_input_clear_error_no_output(probe_files, args, needle):
    d = probe_files
    (d / "bad.json").write_text("{broken")
    r = runner.invoke(app, [a.format(d=d) for a in args])
    assert r.exit_code != 0
    assert needle in r.output
    assert not (d / "o.json").exists() and not (d / "o.png").exists()
    assert not [p for p in d.iterdir() if p.name.startswith(".o.")]  # no temp leftovers


def test_module_help_runs():
    """The light group's help through the one entry point (``light/cli.py`` is not run on
    its own: its errors are printed by ``arlight.cli.main``), with the mounted commands."""
    r = subprocess.run([sys.executable, "-m", "arlight.cli", "light", "--help"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    assert all(c in r.stdout for c in ("estimate", "show", "probeless", "atlas"))


def test_fisheye_kind_with_json_calibration(tmp_path, make_smooth):
    from arlight.sphere.fisheye import FisheyeCamera

    cam = FisheyeCamera.equidistant((200, 200), fov_deg=180)
    img, _ = from_equirect(make_smooth(64), "fisheye", (200, 200), camera=cam)
    write_exr(tmp_path / "fish.exr", img)
    (tmp_path / "cal.json").write_text(json.dumps({"K": cam.K.tolist(), "size": [200, 200]}))
    out = tmp_path / "f.json"
    r = runner.invoke(app, ["estimate", str(tmp_path / "fish.exr"), "--kind", "fisheye",
                            "--fisheye-calib", str(tmp_path / "cal.json"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    est = LightEstimate.load(out)
    assert est.confidence == pytest.approx(0.5, abs=0.01)
    assert est.main_direction @ np.array([0.6, 0.64, 0.48]) > 0.9


def test_calibration_fov_wins_over_the_cli_default(tmp_path, make_smooth):
    """A calibration's fov_deg is used unless --fov is given (the observed fraction shows
    which one was used). Rejects a CLI default of 180 that silently overrides the file."""
    from arlight.sphere.fisheye import FisheyeCamera

    cam = FisheyeCamera.equidistant((200, 200), fov_deg=180)
    img, _ = from_equirect(make_smooth(64), "fisheye", (200, 200), camera=cam)
    write_exr(tmp_path / "fish.exr", img)
    (tmp_path / "cal.json").write_text(json.dumps({"K": cam.K.tolist(), "size": [200, 200],
                                                   "fov_deg": 120}))
    base = ["estimate", str(tmp_path / "fish.exr"), "--kind", "fisheye", "--fisheye-calib",
            str(tmp_path / "cal.json"), "-o", str(tmp_path / "f.json")]
    assert runner.invoke(app, base).exit_code == 0
    assert LightEstimate.load(tmp_path / "f.json").confidence == pytest.approx(0.25, abs=0.01)
    assert runner.invoke(app, [*base, "--fov", "180"]).exit_code == 0
    assert LightEstimate.load(tmp_path / "f.json").confidence == pytest.approx(0.5, abs=0.01)


def test_folder_is_not_file_not_found(tmp_path):
    """A folder given as the image (or calibration) says so, exit 2. Rejects the generic
    'file not found' message."""
    r = runner.invoke(app, ["estimate", str(tmp_path), "-o", str(tmp_path / "o.json")])
    assert r.exit_code == 2 and "is a folder" in r.output and "not found" not in r.output
    img = tmp_path / "f.exr"
    write_exr(img, np.ones((20, 20, 3), np.float32))
    r = runner.invoke(app, ["estimate", str(img), "--kind", "fisheye", "--fisheye-calib",
                            str(tmp_path), "-o", str(tmp_path / "o.json")])
    assert r.exit_code == 2 and "is a folder" in r.output
    assert not (tmp_path / "o.json").exists()


def test_saturated_ldr_input_warns(tmp_path):
    """An 8-bit capture with many pixels at 255 warns that the light is underestimated;
    an unclipped one does not. Rejects estimating silently from clipped whites."""
    import imageio.v3 as iio

    from arlight.sphere.fisheye import FisheyeCamera

    cam = FisheyeCamera.equidistant((120, 120), fov_deg=180)
    d, valid = cam.unproject(cam.pixel_centres())
    codes = np.where((d[..., 1] > 0.8)[..., None] & valid[..., None], 255, 90).astype(np.uint8)
    iio.imwrite(tmp_path / "sat.png", codes.repeat(3, axis=-1))
    iio.imwrite(tmp_path / "ok.png", np.full((120, 120, 3), 90, np.uint8))
    for name, warned in (("sat.png", True), ("ok.png", False)):
        r = runner.invoke(app, ["estimate", str(tmp_path / name), "--kind", "fisheye",
                                "-o", str(tmp_path / f"{name}.json")])
        assert r.exit_code == 0, r.output
        assert ("clipped at white" in r.output) is warned


def test_ball_pose_options_and_blind_cone(tmp_path):
    """--ball-look/--ball-up set the camera pose: a sun seen by a camera looking along +X
    is found where it is, and the blind cone behind the ball lowers the confidence below 1.
    Rejects ignoring the pose (the sun would come out rotated by 90 deg)."""
    from arlight.light.cli import ball_pose, ball_seen_half_angle

    np.testing.assert_allclose(ball_pose("0,0,-1", "0,1,0"), np.diag([1.0, -1.0, -1.0]))
    sun = np.array([-0.6, 0.6, 0.52])
    sun /= np.linalg.norm(sun)
    from arlight.sphere.envmap import equirect_directions

    d = equirect_directions(128)
    env = np.full(d.shape, 0.3, np.float32)
    env[d @ sun > np.cos(np.radians(3))] = 800.0
    pose = ball_pose("1,0,0", "0,1,0")
    ball, _ = from_equirect(env, "ball", 400, center=(200, 200), radius=199,
                            world_from_camera=pose)
    write_exr(tmp_path / "ball.exr", ball)
    out = tmp_path / "b.json"
    args = ["estimate", str(tmp_path / "ball.exr"), "--kind", "ball", "--ball-center",
            "200,200", "--ball-radius", "199", "-o", str(out)]
    r = runner.invoke(app, [*args, "--ball-look", "1,0,0", "--ball-up", "0,1,0"])
    assert r.exit_code == 0, r.output
    est = LightEstimate.load(out)
    assert np.degrees(np.arccos(est.main_direction @ sun)) < 1.0
    expect = (1 - np.cos(ball_seen_half_angle())) / 2
    assert est.confidence == pytest.approx(expect, abs=0.01) and est.confidence < 0.97
    r = runner.invoke(app, [*args, "--ball-look", "0,1,0", "--ball-up", "0,1,0"])
    assert r.exit_code == 2 and "parallel" in r.output


def test_show_circle_area_proportional_to_power():
    """Circle areas are proportional to power (half the power, half the area), as the docs
    say. Rejects the old offset scale 30 + 300 p / p_max."""
    from arlight.light.cli import CIRCLE_AREA_MAX, circle_areas

    np.testing.assert_allclose(circle_areas([4.0, 2.0, 1.0, 0.0]),
                               CIRCLE_AREA_MAX * np.array([1.0, 0.5, 0.25, 0.0]))


def test_show_negative_sh_radiance_is_not_clipped(tmp_path):
    """An SH reconstruction that rings below zero is shown as signed luminance (diverging
    map) with its negative values intact; a positive one as colour. Rejects clipping to
    [0, 1] before display."""
    from arlight.light.cli import render_picture, sh_panel
    from arlight.sphere import sh

    ring = sh.sh_to_equirect(sh.directional_light_coeffs([0, 1, 0], [5, 5, 5], 2), 32)
    assert ring.min() < 0
    panel, diverging = sh_panel(ring)
    assert diverging and panel.min() == pytest.approx(float((ring @ sh.LUMINANCE).min()))
    _, diverging = sh_panel(np.abs(ring))
    assert not diverging
    est = LightEstimate(sh=sh.directional_light_coeffs([0, 1, 0], [5, 5, 5], 2))
    png = render_picture(est, tmp_path / "ring.png")
    assert png.read_bytes()[:4] == b"\x89PNG"
