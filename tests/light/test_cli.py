"""The ``arlight light`` CLI: estimate / show, clear errors, no partial outputs."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from arlight.io.images import write_exr
from arlight.light.cli import app
from arlight.light.estimate import LightEstimate
from arlight.sphere.envmap import from_equirect

runner = CliRunner()


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
    r = subprocess.run([sys.executable, "-m", "arlight.light.cli", "--help"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "estimate" in r.stdout


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
    assert est.confidence == pytest.approx(0.5)
    assert est.main_direction @ np.array([0.6, 0.64, 0.48]) > 0.9
