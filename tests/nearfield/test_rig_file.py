"""cams.toml is read through the scene schema's Validator: every error names file and field."""

from __future__ import annotations

import pytest

from arlight.errors import InputError
from arlight.nearfield.cameras import load_rig

GOOD = """[[cameras]]
name = "front"
position = [0.0, 1.0, 0.9]
look = [0.0, 0.0, -1.0]
equidistant = { size = [64, 64], fov_deg = 180.0 }
"""


@pytest.mark.parametrize("change,field", [
    ('colour = "red"\n', "cameras[0].colour"),  # unknown field (was silently ignored)
    ("up = [0.0, 0.0, -2.0]\n", "cameras[0].up"),  # parallel to look
    ("up = [0.0, 0.0, 0.0]\n", "cameras[0].up"),
    ('fov_deg = "wide"\n', "cameras[0].fov_deg"),
    ("image = 5\n", "cameras[0].image"),
])
def test_bad_camera_fields_name_the_field(tmp_path, change, field):
    f = tmp_path / "cams.toml"
    f.write_text(GOOD + change)
    with pytest.raises(InputError) as e:
        load_rig(f)
    assert e.value.file == str(f) and e.value.field == field


@pytest.mark.parametrize("lens,field", [
    ("{ size = [64.5, 64] }", "cameras[0].equidistant.size"),
    ("{ size = [4, 64] }", "cameras[0].equidistant.size"),
    ("{ size = [64, 64], fov_deg = 0 }", "cameras[0].equidistant.fov_deg"),
    ("{ size = [64, 64], lens = 1 }", "cameras[0].equidistant.lens"),
])
def test_bad_lens_names_the_field(tmp_path, lens, field):
    f = tmp_path / "cams.toml"
    f.write_text(GOOD.replace("{ size = [64, 64], fov_deg = 180.0 }", lens))
    with pytest.raises(InputError) as e:
        load_rig(f)
    assert e.value.field == field


def test_a_good_rig_loads(tmp_path):
    f = tmp_path / "cams.toml"
    f.write_text(GOOD)
    (cam,) = load_rig(f)
    assert cam.name == "front" and cam.model.size == (64, 64)
