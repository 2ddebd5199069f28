"""``light show``: bad light data is an input error; outputs are guarded (issue #28)."""

from __future__ import annotations

import json

import pytest

from arlight.cli import app
from arlight.errors import InputError
from arlight.light.estimate import LightEstimate
from tests.cli_invoke import MainRunner

LIGHT = {"format": "arlight.light_estimate", "version": 1,
         "main_light": {"direction_to_light": [0, 1, 0], "irradiance": [1, 1, 1]},
         "sh": {"coefficients": [[0.1, 0.1, 0.1]] * 4}, "lights": []}


@pytest.mark.parametrize("key,value,field", [
    ("sh", {"coefficients": [[float("nan"), 0, 0]] * 4}, "sh.coefficients"),
    ("lights", 5, "lights"),
    ("main_light", {"direction_to_light": [0, 1, 0], "irradiance": [-1, 0, 0]},
     "main_light.irradiance"),
])
def test_bad_light_data_names_file_and_field(tmp_path, key, value, field):
    """Old behaviour: NaN SH pictured with exit 0; "lights": 5 a TypeError."""
    f = tmp_path / "l.json"
    f.write_text(json.dumps({**LIGHT, key: value}))
    with pytest.raises(InputError) as e:
        LightEstimate.load(f)
    assert e.value.file == str(f) and e.value.field == field
    r = MainRunner().invoke(app, ["light", "show", str(f), "-o", str(tmp_path / "x.png")])
    assert r.exit_code == 2 and not (tmp_path / "x.png").exists()


def test_show_rewrites_its_own_picture_but_not_a_persons(tmp_path):
    f = tmp_path / "l.json"
    f.write_text(json.dumps(LIGHT))
    out = tmp_path / "x.png"
    for _ in range(2):
        assert MainRunner().invoke(app, ["light", "show", str(f), "-o", str(out)]).exit_code == 0
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"mine")
    r = MainRunner().invoke(app, ["light", "show", str(f), "-o", str(mine)])
    assert r.exit_code == 2 and "--overwrite" in r.output and mine.read_bytes() == b"mine"
    r = MainRunner().invoke(app, ["light", "show", str(f), "-o", str(f)])
    assert r.exit_code == 2 and json.loads(f.read_text()) == LIGHT
