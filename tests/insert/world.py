"""A synthetic table top with a printed ChArUco board, for tests with known truth.

The board image comes from OpenCV (``CharucoBoard.generateImage``) and is embedded in a
wood-coloured table texture; the table is a rectangle laid out like the insert pipeline's
plane (:func:`arlight.insert.proxy.plane_shape`: texture rows along +Z, columns along +X), so
the printed board occupies ``0 ≤ X ≤ 5·SQUARE``, ``0 ≤ Z ≤ 7·SQUARE`` exactly as the
registration's board frame says. Camera, light and albedo are known.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from arlight.camera_response import srgb_decode
from arlight.insert.proxy import plane_shape
from arlight.io.images import write_png
from arlight.scene.camera import look_at

SQUARES = (5, 7)
SQUARE = 0.05
MARKER = 0.04
DICT = "DICT_4X4_50"
MARKER_SPEC = f"charuco:{SQUARES[0]}x{SQUARES[1]}:{SQUARE}:{MARKER}:{DICT}"
WOOD = np.array([150, 110, 80], np.uint8)
"""Table colour (sRGB codes); its albedo is :data:`WOOD_ALBEDO`."""
WOOD_ALBEDO = srgb_decode(WOOD / 255.0)
TABLE_LO, TABLE_HI = (-0.6, -0.5), (0.8, 0.9)  # (X, Z) corners of the table, m
PX_PER_M = 800
SUN_TO = (-0.8, 1.0, 0.2)  # towards the sun, board frame
SUN_E = 3.0
AMBIENT = 0.3
LIGHT = f"sun:{SUN_TO[0]},{SUN_TO[1]},{SUN_TO[2]}:{SUN_E}:{AMBIENT}"


def table_texture(path: Path) -> Path:
    """Wood texture with the board printed at its place (black 20, white 235 codes)."""
    w = int(round((TABLE_HI[0] - TABLE_LO[0]) * PX_PER_M))
    h = int(round((TABLE_HI[1] - TABLE_LO[1]) * PX_PER_M))
    tex = np.broadcast_to(WOOD, (h, w, 3)).copy()
    board = cv2.aruco.CharucoBoard(SQUARES, SQUARE, MARKER,
                                   cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICT)))
    bw, bh = (int(round(n * SQUARE * PX_PER_M)) for n in SQUARES)
    img = board.generateImage((bw, bh), marginSize=0)
    printed = (20 + img.astype(np.float64) / 255 * 215).round().astype(np.uint8)
    c0 = int(round(-TABLE_LO[0] * PX_PER_M))
    r0 = int(round(-TABLE_LO[1] * PX_PER_M))
    tex[r0:r0 + bh, c0:c0 + bw] = printed[..., None]
    return write_png(path, tex)


def sphere_mesh(path: Path, radius: float) -> Path:
    """An icosphere centred on the origin (``--at`` names its lowest point, so the pipeline
    must lift it by ``radius``)."""
    import trimesh

    trimesh.creation.icosphere(subdivisions=3, radius=radius).export(path)
    return path


def world(folder: Path, resolution: tuple[int, int], fx: float, origin, target,
          obj: Path | None = None, at=(0.0, 0.0, 0.0), radius: float = 0.0) -> dict:
    """The world (scene dict): textured table, sun + ambient, optional centred sphere mesh
    ``obj`` of ``radius`` standing on the table at ``at``."""
    tex = table_texture(folder / "table.png")
    w, h = resolution
    shapes = [{**plane_shape(TABLE_LO, TABLE_HI, {"type": "diffuse", "texture": str(tex)}),
               "name": "table"}]
    if obj is not None:
        shapes.append({"name": "object", "role": "virtual", "type": "mesh", "file": str(obj),
                       "transform": {"translate": [at[0], at[1] + radius, at[2]]},
                       "material": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}})
    d = np.asarray(SUN_TO, float)
    return {"camera": {"resolution": [w, h],
                       "intrinsics": {"fx": fx, "fy": fx, "cx": w / 2, "cy": h / 2},
                       "world_from_camera": look_at(origin, target).tolist()},
            "shapes": shapes,
            "lights": [{"type": "directional", "direction": (-d / np.linalg.norm(d)).tolist(),
                        "irradiance": [SUN_E] * 3},
                       {"type": "constant", "radiance": [AMBIENT] * 3}]}


def opencv_K(fx: float, w: int, h: int) -> np.ndarray:
    """The world camera's K in OpenCV's pixel convention (centres at integers)."""
    return np.array([[fx, 0, w / 2 - 0.5], [0, fx, h / 2 - 0.5], [0, 0, 1.0]])


def distort(image: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """What a camera with distortion ``dist`` would have taken: each output (distorted) pixel
    looks up the pinhole image where its undistorted ray lands (bilinear)."""
    h, w = image.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.stack([u.ravel(), v.ravel()], axis=1)[:, None]
    und = cv2.undistortPoints(pts, K, dist, R=None, P=K,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50,
                                        1e-9))
    m = und.reshape(h, w, 2).astype(np.float32)
    return cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
