"""Bad-input cases of glTF / USD models and ``pbr`` materials (issue #34) for the fast-tier
bad-input suite (``tests/test_cli_contract.py`` runs them with its own cases): ``validate``
and ``render`` of scene files naming bad models or pbr fields.

Contract for every case: exit 2, one ``error:`` line naming the model (or scene) file and
the field at fault, no traceback, an earlier output folder left byte for byte as it was.
Everything is detected before a render starts (huge textures from their headers).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arlight.io.images import write_png
from tests.cli_harness import Case, previous_output
from tests.conftest import area_light_scene
from tests.scene.model_files import GLB, gltf, png_header_only, usda


def _models(root: Path) -> list[tuple[str, Path, str]]:
    """(case name, bad model file, a field its message must name)."""
    png_header_only(root / "huge.png", 5000, 5000)
    (root / "garbage.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    (root / "garbage.usdz").write_bytes(b"PK\x03\x04 garbage")
    return [
        ("draco", gltf(root / "draco.glb", extension="KHR_draco_mesh_compression"),
         "KHR_draco_mesh_compression"),
        ("ktx2", gltf(root / "ktx2.glb", extension="KHR_texture_basisu"), "KHR_texture_basisu"),
        ("required-ext", gltf(root / "req.glb", required="EXT_unknown"), "extensionsRequired"),
        ("missing-texture", gltf(root / "mt.gltf", image_uri="nope.png"), "images[0].uri"),
        ("huge-texture", gltf(root / "huge.gltf", image_uri="huge.png"), "images[0]"),
        ("degenerate", gltf(root / "deg.glb", degenerate=True), "primitives[0].indices"),
        ("non-manifold", gltf(root / "nm.glb", nonmanifold=True), "non-manifold"),
        ("absurd-scale", gltf(root / "big.glb", node_scale=1e6), "scale"),
        ("garbage-glb", root / "garbage.glb", "garbage.glb"),
        ("usd-missing-texture", usda(root / "mt.usda", texture="nope.png"), "inputs:file"),
        ("usd-absurd-unit", usda(root / "km.usda", meters_per_unit=1000.0, size=100.0),
         "scale"),
        ("garbage-usdz", root / "garbage.usdz", "garbage.usdz"),
    ]


def model_cases(root: Path) -> list[Case]:
    """The cases (files written in ``root/models``)."""
    root = root / "models"
    root.mkdir()
    cases = []
    base = area_light_scene(16, 12)
    write_png(root / "frame.png", np.full((12, 16, 3), 90, np.uint8))
    for i, (name, model, needle) in enumerate(_models(root)):
        d = json.loads(json.dumps(base))
        d["shapes"][-1] = {"name": "obj", "role": "virtual", "type": "model",
                           "file": str(model)}
        d["frame"] = {"image": "frame.png"}
        f = root / f"model_{name}.json"
        f.write_text(json.dumps(d))
        cases.append(Case(f"validate-model-{name}", ["validate", str(f)], [needle]))
        if i % 3 == 0:  # some through render, with an existing output folder
            prev = previous_output(root, f"prev_model_{name}".replace("-", "_"))
            cases.append(Case(f"render-model-{name}", ["render", str(f), "--spp", "1", "-o",
                                                     str(prev)], [needle], keep=prev))
    # a selection that matches nothing; pbr materials in scene files
    bad_tables = {
        "select": ({"type": "model", "file": str(GLB), "select": "nope"}, "nope"),
        "pbr-texture-missing": ({"type": "sphere", "material": {
            "type": "pbr", "base_color_texture": "missing.png"}},
            "shapes[2].material.base_color_texture"),
        "pbr-texture-huge": ({"type": "sphere", "material": {
            "type": "pbr", "normal_texture": "huge.png"}}, "shapes[2].material.normal_texture"),
        "pbr-alpha-mode": ({"type": "sphere", "material": {"type": "pbr", "alpha_mode": "fog"}},
                           "shapes[2].material.alpha_mode"),
        "pbr-metallic": ({"type": "sphere", "material": {"type": "pbr", "metallic": 2.0}},
                         "shapes[2].material.metallic"),
    }
    last = len(base["shapes"]) - 1
    for name, (table, needle) in bad_tables.items():
        needle = needle.replace("shapes[2]", f"shapes[{last}]")
        d = json.loads(json.dumps(base))
        d["shapes"][-1] = {"name": "obj", "role": "virtual", **table}
        f = root / f"bad_{name}.json"
        f.write_text(json.dumps(d))
        cases.append(Case(f"validate-{name}", ["validate", str(f)], [needle]))
    return cases
