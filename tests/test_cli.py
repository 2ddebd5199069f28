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
    # no temporary files left behind: only the manifest of the output set, no staging
    assert [p.name for p in out.glob(".*")] == [".arlight-output.json"]
    assert [p.name for p in tmp_path.glob(".*")] == []
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


def _mirror_ball_scene(tmp_path):
    """16×12 area-light room with a virtual mirror ball (reprojection applies) and a frame."""
    d = area_light_scene(16, 12)
    d["shapes"][-1]["material"] = {"type": "mirror", "reflectance": 0.9}
    write_png(tmp_path / "frame.png", np.full((12, 16, 3), 90, np.uint8))
    d["frame"] = {"image": "frame.png"}
    return _scene_file(tmp_path, d)


def test_render_option_reproject_false_reaches_onepass(tmp_path, capsys):
    """``--option reproject=false`` through the console entry turns reprojection off, and
    the stage timings are printed and stored. Bugs caught: the string "false" taken as
    truthy, options dropped between the CLI and the method, stats.json without stages."""
    p = _mirror_ball_scene(tmp_path)
    base = ["render", str(p), "-m", "onepass", "--spp", "4"]
    assert main([*base, "-o", str(tmp_path / "on")]) == 0
    assert main([*base, "--option", "reproject=false", "-o", str(tmp_path / "off")]) == 0
    on = json.loads((tmp_path / "on" / "stats.json").read_text())
    off = json.loads((tmp_path / "off" / "stats.json").read_text())
    assert on["rays_reprojection"] > 0 and off["rays_reprojection"] == 0
    assert {"time_prepare", "time_trace", "time_assemble"} <= set(off)
    assert "stages: prepare" in capsys.readouterr().err


def test_render_bad_options_exit_2_and_name_the_option(tmp_path, capsys):
    """Bugs caught: an unknown option silently ignored (reference used to), a bad value
    rendered with the default."""
    def err() -> str:  # the console wraps long lines
        return " ".join(capsys.readouterr().err.split())

    p = _mirror_ball_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["render", str(p), "-m", "onepass", "--option", "reproject=maybe",
                 "-o", str(out)]) == 2
    assert "options.reproject: expected true or false" in err()
    assert main(["render", str(p), "--option", "reproject=false", "-o", str(out)]) == 2
    assert ("options.reproject: unknown option; known options: delta, denoise, denoise_aux, "
            "denoise_aux_spp, denoise_device, denoise_quality, denoise_target, replicas, "
            "sampler") in err()
    assert main(["render", str(p), "-m", "onepass", "--option", "bogus", "-o", str(out)]) == 2
    assert not out.exists()


def test_methods_lists_and_describes(capsys):
    """``arlight methods`` lists every method; ``arlight methods NAME`` prints description,
    capabilities and the options table. Bug caught: an option missing from the table."""
    assert main(["methods"]) == 0
    listing = capsys.readouterr().out
    assert "reference" in listing and "onepass" in listing
    assert main(["methods", "onepass"]) == 0
    text = capsys.readouterr().out
    for word in ("Kán", "interactive", "progressive", "materials", "env_mode",
                 "mirror_lower_hemisphere", "reproject", "mode", "miss_only", "default"):
        assert word in text, word
    assert main(["methods", "reference"]) == 0
    text = capsys.readouterr().out
    assert "sampler" in text and "replicas" in text and "multijitter" in text
    assert main(["methods", "nope"]) == 2
