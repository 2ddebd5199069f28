"""What a model file (glTF, USD) becomes: parts in the model's world space, in metres, +Y up.

A :class:`ModelPart` is one triangle mesh with one material: glTF's mesh primitive under a
node, USD's ``Mesh`` prim (one part per ``GeomSubset`` material binding is not split: the
prim's bound material is used). Readers raise :class:`ModelError` naming the field *inside*
the model file (``meshes[0].primitives[1].attributes.TEXCOORD_0``, ``/Root/Body.points``);
:func:`check_model` runs the checks every format shares (degenerate geometry, scale).
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MIN_EXTENT_M = 1e-4
"""Smallest bounding-box diagonal a model may have after unit conversion (0.1 mm)."""
MAX_EXTENT_M = 1e4
"""Largest bounding-box diagonal a model may have after unit conversion (10 km): an AR
object that large is a unit mistake (centimetres read as metres, or worse)."""
MAX_TRIANGLES = 5_000_000
"""Most triangles one model may hold (estimated from accessor/attribute counts before any
buffer is decoded)."""


class ModelError(ValueError):
    """A bad model file; ``field`` is the path of the offending entry inside the file."""

    def __init__(self, message: str, field: str):
        super().__init__(message)
        self.message = message
        self.field = field


class ModelWarning(UserWarning):
    """Something in a model file that arlight loads only partly (animation, skinning,
    morph targets: the static pose is loaded)."""


def _show_model_warning(message, category, filename, lineno, file=None, line=None):
    """Python's warning display, except that a :class:`ModelWarning` is one line,
    ``warning: <file>: <field>: <message>`` (no source location: the model file is the
    place to look)."""
    if isinstance(category, type) and issubclass(category, ModelWarning):
        stream = file if file is not None else sys.stderr
        try:
            stream.write(f"warning: {message}\n")
        except OSError:
            pass
        return
    _SHOW_WARNING(message, category, filename, lineno, file, line)


_SHOW_WARNING = warnings.showwarning
warnings.showwarning = _show_model_warning


@dataclass(frozen=True)
class ModelPart:
    """One mesh of a model, flattened to the model's world space.

    Attributes:
        name: the part's name (glTF node name + primitive index, or the USD prim path).
        vertices: ``(V, 3)`` float64 positions, metres, +Y up (the format's units and up axis
            converted).
        faces: ``(F, 3)`` int64 vertex indices, counter-clockwise seen from the front.
        uv: ``(V, 2)`` float64 texture coordinates, v = 0 at the top row of the textures
            (glTF's convention; USD's ``st`` is flipped on import), or None.
        normals: ``(V, 3)`` unit vertex normals in the same space, or None (recompute).
        tangents: ``(V, 4)`` tangents (xyz, w = bitangent sign) in the same space, or None.
        material: the part's ``pbr`` parameter table (textures as
            :class:`arlight.scene.pbr.Texture`), as :mod:`arlight.scene.schema` describes.
        material_name: the material's name in the file.
        where: the part's path in the file for messages (glTF
            ``meshes[i].primitives[j]``; USD: the prim path).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    normals: np.ndarray | None
    tangents: np.ndarray | None
    material: dict[str, Any]
    material_name: str
    where: str = ""


@dataclass
class Model:
    """The parts of a model file and what it could not load (warnings already issued)."""

    parts: list[ModelPart]
    notes: list[str] = field(default_factory=list)


def warn(model: Model, file: str, where: str, message: str) -> None:
    """Record and issue a :class:`ModelWarning` naming the file and the field."""
    text = f"{file}: {where}: {message}"
    model.notes.append(text)
    warnings.warn(text, ModelWarning, stacklevel=3)


def check_model(model: Model) -> None:
    """Checks every format shares; raises :class:`ModelError`.

    * no parts (nothing to render, or a selection that matched nothing);
    * a part whose triangles all have zero area, or non-finite positions;
    * a bounding box smaller than :data:`MIN_EXTENT_M` or larger than :data:`MAX_EXTENT_M`.

    * a non-manifold part: an edge (between welded positions) shared by more than two
      triangles — inside/outside is undefined there, which breaks refraction, the
      real-time methods' per-vertex transfer and voxelisation.

    Degenerate triangles among good ones are dropped by the renderer and allowed, and so are
    open boundaries (an edge of one triangle: a leaf, a label).
    """
    if not model.parts:
        raise ModelError("the file has no triangle meshes to load", "meshes")
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for part in model.parts:
        v, f = part.vertices, part.faces
        at = part.where or part.name
        if not np.all(np.isfinite(v)):
            raise ModelError("non-finite vertex positions", f"{at}.positions")
        if len(f) == 0:
            raise ModelError("no triangles", f"{at}.indices")
        if f.min() < 0 or f.max() >= len(v):
            raise ModelError(f"indices reach vertex {int(f.max())} of {len(v)}",
                             f"{at}.indices")
        p = v[f]
        area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        if not np.any(area > 0):
            raise ModelError(f"all {len(f)} triangles are degenerate (zero area)",
                             f"{at}.indices")
        _check_manifold(part, at)
        lo = np.minimum(lo, v.min(axis=0))
        hi = np.maximum(hi, v.max(axis=0))
    size = float(np.linalg.norm(hi - lo))
    if not MIN_EXTENT_M <= size <= MAX_EXTENT_M:
        raise ModelError(f"the model is {size:.3g} m across after unit conversion, outside "
                         f"[{MIN_EXTENT_M:g}, {MAX_EXTENT_M:g}] m: a unit or scale mistake "
                         "(glTF is in metres; USD's metersPerUnit gives its unit)", "scale")


def _check_manifold(part: ModelPart, at: str) -> None:
    """:class:`ModelError` if an edge is shared by more than two non-degenerate triangles
    (vertices at the same position count as one, so texture seams are not edges)."""
    _, weld = np.unique(part.vertices, axis=0, return_inverse=True)
    f = weld.ravel()[part.faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    if counts.size and counts.max() > 2:
        k = int(np.argmax(counts))
        a, b = part.vertices[np.argmax(weld.ravel() == uniq[k, 0])], \
            part.vertices[np.argmax(weld.ravel() == uniq[k, 1])]
        raise ModelError(f"non-manifold: {int((counts > 2).sum())} edge(s) shared by more "
                         f"than two triangles (e.g. {int(counts[k])} at {np.round(a, 4).tolist()}"
                         f"–{np.round(b, 4).tolist()})", f"{at}.indices")
