"""A scene file's ``type = "model"`` entry expanded into mesh shapes, one per model part.

Each part of the glTF/USD file (:func:`arlight.scene.models.read_model`) becomes a ``mesh``
shape named ``<entry>/<part>`` (just ``<entry>`` when the file has one part), with the entry's
role and transform (applied after the file's own node transforms and unit conversion), the
file's ``pbr`` material (unless the entry gives ``material``, which then replaces every
part's), and ``Shape.group`` = the entry's name so that object transforms and
:func:`arlight.scene.save.save_scene` address the model as one.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from arlight.scene.mesh import vertex_normals
from arlight.scene.model import Material, MeshData, Shape
from arlight.scene.models import GLTF_SUFFIXES, ModelPart, read_model
from arlight.scene.schema import Validator


def part_mesh(part: ModelPart, flat_default: bool) -> MeshData:
    """The :class:`MeshData` of a part: its own normals, else flat faces (glTF's rule,
    ``flat_default``) or smooth recomputed normals (USD)."""
    if part.normals is not None and np.all(np.linalg.norm(part.normals, axis=1) > 0):
        normals, source = part.normals, "file"
    elif flat_default:
        normals, source = None, "flat"
    else:
        normals, source = vertex_normals(part.vertices, part.faces), "recompute"
    return MeshData(part.vertices.astype(np.float32), part.faces.astype(np.uint32),
                    None if part.uv is None else part.uv.astype(np.float32),
                    None if normals is None else normals.astype(np.float32), source)


def part_material(model_file: str, part: ModelPart) -> Material:
    """The part's ``pbr`` material, named ``<file name>:<material name>``."""
    from arlight.scene.pbr import warn_unrendered

    warn_unrendered(part.material, f"{model_file}: {part.where or part.name}.material")
    return Material(f"{Path(model_file).name}:{part.material_name}", "pbr", part.material)


def expand_model(v: Validator, entry: Shape, field: str, own_material: bool) -> list[Shape]:
    """The mesh shapes of a validated ``model`` entry (``v`` only names the scene file in
    messages; model errors name the model file and the field inside it)."""
    del v, field  # errors come from read_model, naming the model file
    path = entry.params["file"]
    model = read_model(path, entry.params.get("select"))
    flat = Path(path).suffix.lower() in GLTF_SUFFIXES
    many = len(model.parts) > 1
    out = []
    for part in model.parts:
        mesh = part_mesh(part, flat)
        material = entry.material if own_material else part_material(path, part)
        params = {**entry.params, "part": part.name, "normals": mesh.normals_from,
                  "own_material": own_material}
        out.append(replace(entry, name=f"{entry.name}/{part.name}" if many else entry.name,
                           type="mesh", params=params, material=material, mesh=mesh,
                           group=entry.name))
    return out
