"""The command line: exit codes, one-line errors, outputs."""

import json
import subprocess
import sys

import numpy as np

from arlight.cli import main
from arlight.io.images import write_png
from tests.conftest import area_light_scene


def _scene_file(tmp_path, d):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(d))
    return p


def test_validate_ok_and_bad(tmp_path, capsys):
    p = _scene_file(tmp_path, area_light_scene())
    assert main(["validate", str(p)]) == 0
    assert "1 virtual shapes" in capsys.readouterr().out
    d = area_light_scene()
    d["lights"][0]["type"] = "laser"
    bad = _scene_file(tmp_path, d)
    assert main(["validate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "lights[0].type" in err and "scene.json" in err


def test_render_writes_layers_and_bad_input_writes_nothing(tmp_path):
    d = area_light_scene(16, 12)
    write_png(tmp_path / "frame.png", np.full((12, 16, 3), 90, np.uint8))
    d["frame"] = {"image": "frame.png"}
    p = _scene_file(tmp_path, d)
    out = tmp_path / "out"
    assert main(["render", str(p), "--spp", "4", "-o", str(out)]) == 0
    for name in ("composite.png", "composite.exr", "mixed.exr", "delta.exr", "mask.exr",
                 "real.exr", "stats.json"):
        assert (out / name).is_file(), name
    assert not list(out.glob(".*"))  # no temporary files left behind
    d["frame"] = {"image": "missing.png"}
    bad_out = tmp_path / "bad"
    assert main(["render", str(_scene_file(tmp_path, d)), "-o", str(bad_out)]) == 2
    assert not bad_out.exists()
    assert main(["render", str(p), "--method", "nope", "-o", str(bad_out)]) == 2
    assert not bad_out.exists()


def test_console_script_exit_code(tmp_path):
    r = subprocess.run([sys.executable, "-m", "arlight.cli", "validate",
                        str(tmp_path / "none.toml")], capture_output=True, text=True)
    assert r.returncode == 2 and "scene file not found" in r.stderr
    r = subprocess.run([sys.executable, "-m", "arlight.cli", "methods"], capture_output=True,
                       text=True)
    assert r.returncode == 0 and "reference" in r.stdout


def test_demo_runs(tmp_path):
    assert main(["demo", "--spp", "1", "-o", str(tmp_path)]) == 0
    assert (tmp_path / "composite.png").is_file()
