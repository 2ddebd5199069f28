"""One-off provenance script: how the suite's meshes and environment map were made.

Not imported by arlight and never run at run time (it reads the shared asset folder, which
the package must not). Kept so the decimated files can be regenerated and audited:

    .venv/bin/python src/arlight/data/scenes/make_assets.py /path/to/shared/assets

Every mesh is decimated with quadric edge collapse (trimesh + fast-simplification), turned to
+Y up, scaled to a height of exactly 1 (metres before the scene's ``transform.scale``), centred
on the origin in x and z, and its lowest point put on y = 0, so a scene file places it with
``scale = <height in m>`` and ``translate = [x, floor_y, z]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent

MESHES = {  # output name: (source file, target faces, rotation to +Y up (axis, deg) or None)
    "bunny.ply": ("meshes/bunny.ply", 2500, None),
    "dragon.ply": ("meshes/dragon_vrip_res3.ply", 4000, None),
    "lucy.ply": ("meshes/lucy.ply", 3000, ([1.0, 0.0, 0.0], -90.0)),
}


def normalise(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Scale to unit height, centre in x/z, base on y = 0."""
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2, -lo[1], -(lo[2] + hi[2]) / 2])
    mesh.apply_scale(1.0 / (hi[1] - lo[1]))
    return mesh


def save(mesh: trimesh.Trimesh, name: str) -> None:
    mesh.vertices = np.asarray(mesh.vertices, dtype=np.float32)
    (HERE / "meshes" / name).write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary",
                                                                           vertex_normal=False))
    print(f"{name}: {len(mesh.vertices)} v, {len(mesh.faces)} f")


def main(assets: Path) -> None:
    for name, (src, faces, rot) in MESHES.items():
        m = trimesh.load(assets / src, force="mesh")
        m.remove_unreferenced_vertices()
        m = m.simplify_quadric_decimation(face_count=faces)
        if rot is not None:
            axis, deg = rot
            m.apply_transform(trimesh.transformations.rotation_matrix(np.radians(deg), axis))
        save(normalise(m), name)
    # Ring for glass-ring: torus in the x-y plane (axis +z), outer radius 1, tube radius 0.12.
    ring = trimesh.creation.torus(major_radius=0.88, minor_radius=0.12, major_sections=64,
                                  minor_sections=16)
    save(ring, "ring.ply")

    # Outdoor environment: Poly Haven "rooitou_park" (CC0) 1024×512 → 256×128 by 4×4 box
    # averaging (preserves the mean radiance and the sun's total power).
    from arlight.io.images import read_hdr, write_exr

    env = read_hdr(assets / "hdri/rooitou_park_1k.hdr").astype(np.float64)
    h, w, _ = env.shape
    small = env.reshape(h // 4, 4, w // 4, 4, 3).mean(axis=(1, 3))
    write_exr(HERE / "outdoor-env" / "rooitou_park_256x128.exr", small.astype(np.float32))
    print("rooitou_park_256x128.exr", small.shape, float(small.max()))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python make_assets.py ASSETS_DIR  (the shared assets folder with "
                 "meshes/ and hdri/)")
    main(Path(sys.argv[1]))
