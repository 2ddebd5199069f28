"""``arlight light atlas``: a light file from a rig with HDR images; bad input exits 2 and
writes nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.cli import app
from arlight.io.images import write_exr
from arlight.nearfield.lightfile import load_light
from arlight.scene.save import save_scene
from tests.cli_invoke import MainRunner
from tests.nearfield.conftest import room, scene, vbox

runner = MainRunner()

CAM = ('[[cameras]]\nname = "{name}"\nposition = {pos}\nlook = {look}\nup = {up}\n'
       'equidistant = {{ size = [32, 32], fov_deg = 180.0 }}\n')


@pytest.fixture
def files(tmp_path):
    path = tmp_path / "scene.toml"
    save_scene(scene(room(virtual=[vbox()])), path)
    img = np.full((32, 32, 3), 0.2, np.float32)
    img[12:20, 12:20] = 20.0  # a bright spot
    write_exr(tmp_path / "a.exr", img)
    write_exr(tmp_path / "b.exr", np.full((32, 32, 3), 0.3, np.float32))
    return tmp_path, path


def _rig(tmp, cams, images=True):
    text = ""
    for k, (pos, look) in enumerate(cams):
        up = [0, 0, -1] if look[1] else [0, 1, 0]
        text += CAM.format(name=f"c{k}", pos=pos, look=look, up=up)
        if images:
            text += f'image = "{"ab"[k % 2]}.exr"\n'
    (tmp / "cams.toml").write_text(text)
    return tmp / "cams.toml"


def test_atlas_writes_a_light_file(files):
    tmp, path = files
    rig = _rig(tmp, [([0, 1, 0], [0, 1, 0]), ([0, 1, 0.5], [0, 0, -1])])
    out = tmp / "vals.json"
    r = runner.invoke(app, ["light", "atlas", str(path), "--cameras", str(rig), "--atlas",
                            "48", "--vals", "4", "-o", str(out)])
    assert r.exit_code == 0, r.output
    light = load_light(out)
    assert 1 <= light.count <= 4 and light.n_objects == 1
    assert json.loads(out.read_text())["objects"] == ["obj"]


@pytest.mark.parametrize("case", ["tau", "vals", "uncalibrated", "sees_nothing", "size"])
def test_bad_input_exits_2_and_writes_nothing(files, case):
    tmp, path = files
    rig = _rig(tmp, [([0, 1, 0], [0, 1, 0])])
    args = ["light", "atlas", str(path), "--cameras", str(rig), "--atlas", "32"]
    if case == "tau":
        args += ["--tau", "1.2"]
    elif case == "vals":
        args += ["--vals", "0"]
    elif case == "uncalibrated":
        rig.write_text('[[cameras]]\nname = "x"\nposition = [0, 1, 0]\nlook = [0, 0, -1]\n')
    elif case == "sees_nothing":
        _rig(tmp, [([0, 1, 0], [0, 1, 0]), ([0, 1, 5], [0, 0, 1])])
    elif case == "size":
        (tmp / "a.exr").unlink()
        write_exr(tmp / "a.exr", np.ones((16, 16, 3), np.float32))
    out = tmp / "vals.json"
    r = runner.invoke(app, args + ["-o", str(out)])
    assert r.exit_code == 2, r.output
    expect = {"tau": "τ", "vals": "M must", "uncalibrated": "uncalibrated",
              "sees_nothing": "sees nothing", "size": "does not match"}[case]
    assert expect in r.output
    assert not out.exists()


def test_atlas_default_tau_is_the_servers():
    """``arlight light atlas`` spells τ's default as a literal (a command module imports no
    NumPy); it must be the server's and the method's default. Rejects a default changed in
    one place only."""
    import inspect

    from arlight.methods.nearfield import OPTIONS
    from arlight.nearfield.cli import atlas
    from arlight.nearfield.pipeline import NearFieldSettings
    from arlight.nearfield.split import DEFAULT_TAU

    assert inspect.signature(atlas).parameters["tau"].default == DEFAULT_TAU
    assert NearFieldSettings().tau == OPTIONS["tau"].default == DEFAULT_TAU
