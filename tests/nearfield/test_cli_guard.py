"""``light atlas``: --vals beyond the nearfield method's cap, outputs onto the scene's or the
rig's files (issue #28)."""

from __future__ import annotations

import numpy as np

from arlight.cli import app
from arlight.io.images import write_exr
from arlight.methods.nearfield import OPTIONS
from arlight.nearfield.state import MAX_VALS
from arlight.scene.save import save_scene
from tests.cli_invoke import MainRunner
from tests.nearfield.conftest import room, scene, vbox

RIG = ('[[cameras]]\nname = "c"\nposition = [0, 1, 0]\nlook = [0, 0, -1]\nup = [0, 1, 0]\n'
       'equidistant = { size = [32, 32], fov_deg = 180.0 }\nimage = "a.exr"\n')


def _files(tmp_path):
    save_scene(scene(room(virtual=[vbox()])), tmp_path / "scene.toml")
    write_exr(tmp_path / "a.exr", np.full((32, 32, 3), 0.2, np.float32))
    (tmp_path / "cams.toml").write_text(RIG)
    return ["light", "atlas", str(tmp_path / "scene.toml"), "--cameras",
            str(tmp_path / "cams.toml"), "--atlas", "32"]


def test_vals_beyond_the_render_cap_is_refused(tmp_path):
    """Old behaviour: --vals 1000000000 silently wrote 116 VALs."""
    args = _files(tmp_path)
    cap = MAX_VALS
    assert OPTIONS["vals"].max == MAX_VALS  # the cap the nearfield method renders
    r = MainRunner().invoke(app, [*args, "--vals", str(cap + 1), "-o", str(tmp_path / "v.json")])
    assert r.exit_code == 2 and "--vals" in r.output and not (tmp_path / "v.json").exists()


def test_output_onto_the_rig_image_or_a_persons_file_is_refused(tmp_path):
    args = _files(tmp_path)
    before = (tmp_path / "a.exr").read_bytes()
    r = MainRunner().invoke(app, [*args, "-o", str(tmp_path / "a.exr")])
    assert r.exit_code == 2 and "input" in r.output
    assert (tmp_path / "a.exr").read_bytes() == before
    (tmp_path / "mine.json").write_text("{}")
    r = MainRunner().invoke(app, [*args, "-o", str(tmp_path / "mine.json")])
    assert r.exit_code == 2 and "--overwrite" in r.output
    assert (tmp_path / "mine.json").read_text() == "{}"


def test_atlas_bound_names_force(tmp_path, monkeypatch):
    import arlight.bounds as B

    args = _files(tmp_path)
    monkeypatch.setattr(B, "available_memory", lambda: 1000.0)
    r = MainRunner().invoke(app, [*args, "-o", str(tmp_path / "v.json")])
    assert r.exit_code == 2 and "--force" in r.output and not (tmp_path / "v.json").exists()
