"""Mesh shading normals: kept from PLY/OBJ files, recomputed deterministically, or flat."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from arlight.errors import InputError
from arlight.scene.load import parse_scene
from arlight.scene.mesh import vertex_normals


def _scene(file: str, **mesh) -> dict:
    return {"camera": {"resolution": [8, 6], "fov_y_deg": 40,
                       "look_at": {"origin": [0, 0, 3], "target": [0, 0, 0]}},
            "shapes": [{"role": "virtual", "type": "mesh", "file": file, **mesh}]}


@pytest.fixture
def sphere_files(tmp_path):
    """An icosphere with deliberately tilted stored normals, as PLY and OBJ, and without."""
    m = trimesh.creation.icosphere(1)
    tilted = m.vertex_normals + np.array([0.3, 0.0, 0.0])
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    m2 = trimesh.Trimesh(m.vertices, m.faces, vertex_normals=tilted, process=False)
    m2._cache["vertex_normals"] = tilted  # trimesh exports the cached normals
    (tmp_path / "n.ply").write_bytes(trimesh.exchange.ply.export_ply(m2, vertex_normal=True))
    (tmp_path / "n.obj").write_text(trimesh.exchange.obj.export_obj(m2, include_normals=True))
    (tmp_path / "plain.ply").write_bytes(trimesh.exchange.ply.export_ply(m, vertex_normal=False))
    return tmp_path, tilted


@pytest.mark.parametrize("name", ["n.ply", "n.obj"])
def test_file_normals_are_kept_by_default(sphere_files, name):
    folder, tilted = sphere_files
    mesh = parse_scene(_scene(name), folder).shapes[0].mesh
    assert mesh.normals_from == "file"
    # OBJ readers may reorder vertices: compare normals per position
    order = np.lexsort(mesh.vertices.T)
    ref = trimesh.creation.icosphere(1).vertices
    ref_order = np.lexsort(ref.T.astype(np.float32))
    np.testing.assert_allclose(mesh.normals[order], tilted[ref_order], atol=1e-5)


def test_recompute_and_flat_and_smooth_false(sphere_files):
    folder, tilted = sphere_files
    rec = parse_scene(_scene("n.ply", normals="recompute"), folder).shapes[0].mesh
    assert rec.normals_from == "recompute"
    radial = rec.vertices / np.linalg.norm(rec.vertices, axis=1, keepdims=True)
    assert np.min(np.sum(rec.normals * radial, axis=1)) > 0.98
    for kw in ({"normals": "flat"}, {"smooth": False}):
        flat = parse_scene(_scene("n.ply", **kw), folder).shapes[0].mesh
        assert flat.normals is None and flat.normals_from == "flat"
    auto = parse_scene(_scene("plain.ply"), folder).shapes[0].mesh
    assert auto.normals_from == "recompute"


def test_file_normals_requested_but_missing_or_contradicted(sphere_files):
    folder, _ = sphere_files
    with pytest.raises(InputError, match=r"shapes\[0\]\.normals.*no vertex normals"):
        parse_scene(_scene("plain.ply", normals="file"), folder)
    with pytest.raises(InputError, match=r"shapes\[0\]\.smooth"):
        parse_scene(_scene("n.ply", normals="file", smooth=False), folder)


def test_recomputed_normals_are_welded_across_split_vertices():
    """A vertex split in two (as at a texture seam) gets one normal on both copies."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [0, 1, 0], [-1, 0, 1]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    n = vertex_normals(v, f)
    np.testing.assert_array_equal(n[0], n[3])
    np.testing.assert_array_equal(n[2], n[4])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
