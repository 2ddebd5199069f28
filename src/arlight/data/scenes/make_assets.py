"""Provenance script: how the suite's meshes, textures and environment map were made.

Not imported by arlight and never run at run time (it reads the shared asset folder, which
the package must not). Kept so the files can be regenerated and audited:

    .venv/bin/python src/arlight/data/scenes/make_assets.py               # generated only
    .venv/bin/python src/arlight/data/scenes/make_assets.py /path/to/shared/assets  # + derived

Without an argument only the assets generated from code are written (the ring, the bevelled
cube, the albedo textures of the worlds' imperfect proxies; byte-identical on every run); with
the shared asset folder the third-party meshes and the environment map are derived as well.

Every derived mesh is decimated with quadric edge collapse (trimesh + fast-simplification),
turned to +Y up, scaled to a height of exactly 1 (metres before the scene's
``transform.scale``), centred on the origin in x and z, and its lowest point put on y = 0, so a
scene file places it with ``scale = <height in m>`` and ``translate = [x, floor_y, z]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent

PANORAMAS = ("rooitou_park", "studio_small_03", "st_fagans_interior", "empty_warehouse_01",
             "potsdamer_platz")
"""Poly Haven panoramas bundled for light estimation (benchmarks and tests)."""

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


def bevelled_cube(bevel: float = 0.1) -> trimesh.Trimesh:
    """Unit cube (side 1, centred on the origin) with every edge chamfered at 45° by
    ``bevel`` (a fraction of the side) and every corner cut by a triangle: the convex hull of
    the 24 points (±h, ±a, ±a) and permutations, h = 1/2, a = h − bevel. Flat faces, so scene
    files use it with ``smooth = false``."""
    h, a = 0.5, 0.5 - bevel
    pts = [np.roll([sx * h, sy * a, sz * a], k) for k in range(3)
           for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    return trimesh.convex.convex_hull(np.asarray(pts))


def write_texture(name: str, albedo: np.ndarray) -> None:
    """Write a linear albedo map as an 8-bit sRGB PNG and print the mean of what a loader
    decodes (the flat albedo the proxy's material must carry)."""
    import imageio.v3 as iio

    from arlight.camera_response import srgb_decode, srgb_encode

    codes = np.round(srgb_encode(np.clip(albedo, 0.0, 1.0)) * 255).astype(np.uint8)
    path = HERE / "textures" / name
    path.parent.mkdir(exist_ok=True)
    iio.imwrite(path, codes)
    mean = srgb_decode(codes / 255.0).reshape(-1, 3).mean(axis=0)
    print(f"{name}: {codes.shape[1]}×{codes.shape[0]}, {path.stat().st_size} B, "
          f"mean albedo [{mean[0]:.4f}, {mean[1]:.4f}, {mean[2]:.4f}]")


def tiles(n: int = 5, texels: int = 16, dark: float = 0.15, bright: float = 0.95,
          grout: float = 0.05) -> np.ndarray:
    """An n×n checkerboard of dark and bright tiles with thin dark grout lines (grey)."""
    i = np.arange(n * texels)
    tile = i // texels
    check = (tile[:, None] + tile[None, :]) % 2 == 0
    img = np.where(check, bright, dark)
    edge = (i % texels == 0)
    img = np.where(edge[:, None] | edge[None, :], grout, img)
    return np.repeat(img[..., None], 3, axis=2)


def planks(color, n: int = 8, texels: int = 12, length: int = 96, seed: int = 3) -> np.ndarray:
    """Wooden planks along the texture's x axis: ``n`` planks alternating light and dark
    (×1.45 / ×0.55 of ``color``), each with a sinusoidal grain (±12 %) of random phase and
    frequency, and a dark joint line between planks."""
    rng = np.random.default_rng(seed)
    x = np.arange(length) / length
    rows = []
    for k in range(n):
        level = 1.45 if k % 2 == 0 else 0.55
        freq, phase = rng.integers(3, 7), rng.uniform(0, 2 * np.pi)
        v = np.arange(texels)[:, None] / texels
        grain = 1.0 + 0.12 * np.sin(2 * np.pi * (freq * x[None, :] + 0.7 * v) + phase)
        plank = level * grain
        plank[0, :] = 0.3  # joint
        rows.append(plank)
    mod = np.concatenate(rows, axis=0)
    return mod[..., None] * np.asarray(color, dtype=np.float64)[None, None, :]


def make_generated() -> None:
    """Assets made from code only (no third-party input)."""
    # Ring for glass-ring: torus in the x-y plane (axis +z), outer radius 1, tube radius 0.12.
    ring = trimesh.creation.torus(major_radius=0.88, minor_radius=0.12, major_sections=64,
                                  minor_sections=16)
    save(ring, "ring.ply")
    # glass-ring's real cubes as they are (bevelled); the proxy models them as sharp boxes.
    save(bevelled_cube(), "bevelled_cube.ply")
    # Albedo textures of the worlds; each proxy carries the texture's mean as a flat albedo.
    write_texture("tiles.png", tiles())
    write_texture("planks_grey.png", planks([0.45, 0.45, 0.43]))
    write_texture("planks_brown.png", planks([0.55, 0.42, 0.30], seed=5))


def main(assets: Path | None) -> None:
    make_generated()
    if assets is None:
        return
    for name, (src, faces, rot) in MESHES.items():
        m = trimesh.load(assets / src, force="mesh")
        m.remove_unreferenced_vertices()
        m = m.simplify_quadric_decimation(face_count=faces)
        if rot is not None:
            axis, deg = rot
            m.apply_transform(trimesh.transformations.rotation_matrix(np.radians(deg), axis))
        save(normalise(m), name)

    from arlight.io.images import read_hdr, write_exr

    # Outdoor environment: Poly Haven "rooitou_park" (CC0) 1024×512 → 256×128 by 4×4 box
    # averaging (preserves the mean radiance and the sun's total power).
    small = box_downsample(read_hdr(assets / "hdri/rooitou_park_1k.hdr"), 4)
    write_exr(HERE / "outdoor-env" / "rooitou_park_256x128.exr", small.astype(np.float32))
    print("rooitou_park_256x128.exr", small.shape, float(small.max()))

    # Light-estimation panoramas (arlight/data/light/panoramas/, Poly Haven, CC0): 1024×512 →
    # 512×256 by 2×2 box averaging, written as Radiance RGBE by Mitsuba.
    import mitsuba as mi

    out = HERE.parent / "light" / "panoramas"
    out.mkdir(exist_ok=True)
    for name in PANORAMAS:
        half = box_downsample(read_hdr(assets / f"hdri/{name}_1k.hdr"), 2)
        mi.Bitmap(half.astype(np.float32)).write(str(out / f"{name}_512x256.hdr"))
        print(f"{name}_512x256.hdr", half.shape, float(half.max()))


def box_downsample(image: np.ndarray, k: int) -> np.ndarray:
    """``k × k`` box average of an ``(H, W, 3)`` image (H, W multiples of k), float64: the
    mean radiance, and so every source's total power on the sphere, is kept."""
    h, w, c = image.shape
    return np.asarray(image, np.float64).reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))

if __name__ == "__main__":
    if len(sys.argv) > 2:
        sys.exit("usage: python make_assets.py [ASSETS_DIR]  (the shared assets folder with "
                 "meshes/ and hdri/; without it only the generated assets are written)")
    main(Path(sys.argv[1]) if len(sys.argv) == 2 else None)
