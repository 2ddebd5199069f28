"""``arlight insert``'s guards: numbers, targets, cost and outputs checked before any work.

Each test rejects one wrong implementation, named in its docstring."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from arlight.bounds import image_size
from arlight.errors import InputError
from arlight.insert.numbers import floats, rotation
from arlight.insert.pipeline import (
    InsertRequest,
    _check_request,
    check_insert_output,
    insert_inputs,
)
from arlight.insert.proxy import parse_box
from arlight.insert.registration import parse_marker


@pytest.mark.parametrize("spec", ["charuco:100000x100000:0.04:0.02:DICT_6X6_250",
                                  "charuco:2x1000000:0.04:0.02:DICT_7X7_1000",
                                  "charuco:30x30:0.04:0.02:DICT_6X6_250"])
def test_a_board_larger_than_its_dictionary_is_refused_at_once(spec):
    """Rejects: a board size checked only for >= 2 (100000×100000 reached OpenCV's
    CharucoBoard, 10¹⁰ corners: MemoryError, exit 1)."""
    t = time.perf_counter()
    with pytest.raises(InputError, match="--marker.*markers but DICT_"):
        parse_marker(spec)
    assert time.perf_counter() - t < 1.0
    parse_marker("charuco:22x22:0.04:0.02:DICT_6X6_250")  # 242 markers: printable


def test_marker_id_and_lengths_bounded():
    for bad in ("aruco:0.05:DICT_4X4_50:50", "aruco:nan:DICT_4X4_50",
                "charuco:5x7:0.04:1e-9:DICT_6X6_250", "charuco:5x7:inf:0.02:DICT_6X6_250"):
        with pytest.raises(InputError, match="--marker"):
            parse_marker(bad)
    assert parse_marker("aruco:0.05:DICT_4X4_50:49").marker_id == 49


@pytest.mark.parametrize("text", ["nan,0,0", "0,inf,0", "0,0,-inf", "1e9,0,0", "a,0,0",
                                  "1,2", "1,2,3,4", ""])
def test_one_number_parser_for_every_option(text):
    """``--at`` (insert/cli.py) and ``--box`` (insert/proxy.py) had two copies of the parser
    that diverged: the CLI's accepted inf. Rejects either copy coming back."""
    with pytest.raises(InputError, match="--at"):
        floats(text, 3, "--at")
    with pytest.raises(InputError, match="--box"):
        parse_box(f"{text}:0.1,0.1,0.1")
    from arlight.insert import cli, proxy

    assert not hasattr(cli, "_floats") and not hasattr(proxy, "_floats")


def test_every_number_of_a_request_is_checked_naming_its_option(tmp_path):
    """Rejects: NaN light scale/rotation reported as ``--light`` (or passed on), a NaN or
    zero-axis rotation reaching the transform."""
    base = dict(photo=Path("p.png"), calib=Path("c.json"), marker="m", light="sun:0,1,0:1",
                object=Path("o.obj"))
    for change, field in [({"light_scale": float("nan")}, "--light-scale"),
                          ({"light_scale": 0.0}, "--light-scale"),
                          ({"light_rotation_deg": float("inf")}, "--light-rotation"),
                          ({"rotate": [(0, 1, 0, float("nan"))]}, "--rotate"),
                          ({"rotate": [(0, 0, 0, 30)]}, "--rotate"),
                          ({"at": (0.0, float("nan"), 0.0)}, "--at"),
                          ({"color": (0.5, float("nan"), 0.5)}, "--color"),
                          ({"plane_size": (float("inf"), 1.0)}, "--plane-size")]:
        with pytest.raises(InputError) as e:
            _check_request(InsertRequest(**{**base, **change}))
        assert e.value.field == field, (change, e.value)
    with pytest.raises(InputError, match="--rotate"):
        rotation("0,1,0,1e9")


def test_output_that_is_or_holds_an_input_or_a_referenced_map(tmp_path):
    """Rejects: ``-o`` equal to an input file (reported as "not a folder" without naming
    the input), and a light estimate's HDR map inside ``-o`` missed because only the JSON
    was listed as an input."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "map.exr").write_bytes(b"a map")
    light = tmp_path / "light.json"
    light.write_text(json.dumps({"format": "arlight.light_estimate",
                                 "hdr_map": {"file": "out/map.exr", "mapping": "equirect"}}))
    req = InsertRequest(photo=tmp_path / "p.png", calib=tmp_path / "c.json",
                        marker=str(tmp_path / "board.toml"), light=str(light),
                        object=tmp_path / "o.obj")
    inputs = insert_inputs(req)
    assert {p.name for p in inputs} >= {"p.png", "c.json", "board.toml", "light.json",
                                        "map.exr", "o.obj"}
    with pytest.raises(InputError, match="contains the input .*map.exr"):
        check_insert_output(out, inputs)
    (tmp_path / "p.png").write_bytes(b"photo")
    with pytest.raises(InputError, match=r"is the input .*p\.png") as e:
        check_insert_output(tmp_path / "p.png", inputs)
    assert e.value.field == "--out"


def test_image_size_from_the_header(tmp_path):
    """The cost of a photo or frame comes from its header (nothing decoded)."""
    from arlight.io.images import write_exr, write_png
    from tests.test_cli_contract_sequence_insert import _huge_png

    write_png(tmp_path / "a.png", np.zeros((5, 7, 3), np.uint8))
    write_exr(tmp_path / "a.exr", np.zeros((6, 9, 3), np.float32))
    big = _huge_png(tmp_path / "big.png", 40000, 30000)
    assert image_size(tmp_path / "a.png") == (7, 5)
    assert image_size(tmp_path / "a.exr") == (9, 6)
    assert image_size(big) == (40000, 30000) and big.stat().st_size < 1 << 20
    (tmp_path / "junk.png").write_bytes(b"junk")
    assert image_size(tmp_path / "junk.png") is None
