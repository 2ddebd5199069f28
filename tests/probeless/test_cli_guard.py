"""``light probeless``: outputs never land on or among the RGB-D folder's files; the TSDF
size is bounded before work (issue #28)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.io.images import write_png
from arlight.probeless.cli import run


@pytest.fixture
def seq(tmp_path):
    import cv2

    (tmp_path / "seq" / "color").mkdir(parents=True)
    (tmp_path / "seq" / "depth").mkdir()
    write_png(tmp_path / "seq" / "color" / "0.png", np.full((12, 16, 3), 128, np.uint8))
    cv2.imwrite(str(tmp_path / "seq" / "depth" / "0.png"), np.full((12, 16), 1500, np.uint16))
    (tmp_path / "seq" / "intrinsics.json").write_text(json.dumps(
        {"fx": 20, "fy": 20, "cx": 8, "cy": 6}))
    (tmp_path / "seq" / "poses.txt").write_text("0 0 0 0 0 0 1\n")
    return tmp_path / "seq"


def _snap(folder):
    return {str(p): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("where", ["intrinsics", "colour", "depth-mesh", "new-in-colour"])
def test_outputs_into_the_rgbd_folder_are_refused(seq, tmp_path, where):
    """Old behaviour: -o/--mesh replaced intrinsics.json or a colour/depth image."""
    before = _snap(seq)
    out, mesh = tmp_path / "l.json", None
    if where == "intrinsics":
        out = seq / "intrinsics.json"
    elif where == "colour":
        out = seq / "color" / "0.png"
    elif where == "depth-mesh":
        mesh = seq / "depth" / "0.png"
    else:
        mesh = seq / "color" / "zz.ply"
    with pytest.raises(InputError):
        run(seq, seq / "poses.txt", out, mesh=mesh)
    assert _snap(seq) == before


def test_tsdf_memory_bound_names_force(seq, tmp_path, monkeypatch):
    import arlight.bounds as B

    monkeypatch.setattr(B, "available_memory", lambda: 1e6)
    with pytest.raises(InputError, match="--force"):
        run(seq, seq / "poses.txt", tmp_path / "l.json", resolution=64)
