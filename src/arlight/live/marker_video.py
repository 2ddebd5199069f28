"""A synthetic moving-camera video of a printed ChArUco board on a table (for ``arlight live``).

The table is the plane ``Y = 0`` of the board frame (:data:`arlight.insert.registration.
WORLD_FROM_BOARD`: board x → world X, board y → world Z), a wood-coloured texture with the
board printed on it (OpenCV's ``CharucoBoard.generateImage``). A plane seen by a pinhole
camera is exactly a homography of its texture (Hartley & Zisserman, Eq. 8.1 with the
plane's ``z = 0``: ``x = K [r1 r2 t] X``), so every frame is the texture warped by
``H = K · [c1 c2 t] · T`` where ``[c1 c2 t]`` are columns of ``camera_from_board`` and ``T``
maps texture pixels to board metres; frames are warped at twice the size and box-filtered
down (anti-aliasing). Beyond the table the frame shows a uniform wall.

The camera orbits the board's centre (:func:`orbit`: a yaw swing and a height bob, a
smooth loop), with the intrinsics of :func:`intrinsics` and no lens distortion. What
:func:`write_bundle` writes — the video, its calibration and the AR scene (the table as
real proxy, a virtual bunny on the board, a sun and a sky) — is the bundled
``arlight/data/live`` example.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from arlight.insert.registration import WORLD_FROM_BOARD
from arlight.scene.camera import look_at

SQUARES = (5, 7)
SQUARE_M = 0.04
MARKER_M = 0.03
DICTIONARY = "DICT_4X4_50"
MARKER = f"charuco:{SQUARES[0]}x{SQUARES[1]}:{SQUARE_M}:{MARKER_M}:{DICTIONARY}"
"""The ``--marker`` description of the printed board."""
TABLE_LO, TABLE_HI = (-0.45, -0.35), (0.65, 0.75)
"""(X, Z) corners of the table, m (board frame)."""
PX_PER_M = 1600
"""Texture resolution, pixels per metre."""
WOOD = (150, 110, 80)
WALL = (196, 200, 206)
SIZE = (640, 480)
FPS = 30.0
FRAMES = 90


def intrinsics(size: tuple[int, int] = SIZE) -> np.ndarray:
    """OpenCV K (pixel centres at integers): a 60° horizontal field of view."""
    w, h = size
    f = 0.5 * w / math.tan(math.radians(30.0))
    return np.array([[f, 0.0, w / 2 - 0.5], [0.0, f, h / 2 - 0.5], [0.0, 0.0, 1.0]])


def board_centre() -> np.ndarray:
    """The board's centre in the world (m)."""
    return np.array([SQUARES[0] * SQUARE_M / 2, 0.0, SQUARES[1] * SQUARE_M / 2])


def orbit(n: int = FRAMES, radius: float = 0.4, height: float = 0.34,
          swing_deg: float = 25.0, bob: float = 0.04) -> list[np.ndarray]:
    """``n`` poses ``world_from_camera`` (OpenCV axes) looking at the board's centre from
    ``radius`` m out along +Z (the print's bottom edge) and ``height`` m up, the yaw swinging
    ``±swing_deg`` and the height ``±bob`` m over one period (a seamless loop)."""
    c = board_centre()
    out = []
    for i in range(n):
        u = 2 * math.pi * i / n
        a = math.radians(swing_deg) * math.sin(u)
        o = c + np.array([radius * math.sin(a), height + bob * math.sin(2 * u),
                          radius * math.cos(a)])
        out.append(look_at(o, c))
    return out


def table_texture() -> np.ndarray:
    """``(H, W, 3)`` uint8 sRGB codes: wood with the board printed (black 25, white 235);
    texture row ``v`` ↔ board y = ``TABLE_LO[1] + v / PX_PER_M``, column ``u`` ↔ x."""
    w = int(round((TABLE_HI[0] - TABLE_LO[0]) * PX_PER_M))
    h = int(round((TABLE_HI[1] - TABLE_LO[1]) * PX_PER_M))
    tex = np.broadcast_to(np.array(WOOD, np.uint8), (h, w, 3)).copy()
    dic = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))
    board = cv2.aruco.CharucoBoard(SQUARES, SQUARE_M, MARKER_M, dic)
    bw, bh = (int(round(n * SQUARE_M * PX_PER_M)) for n in SQUARES)
    img = board.generateImage((bw, bh), marginSize=0)
    printed = (25 + img.astype(np.float64) / 255 * 210).round().astype(np.uint8)
    c0 = int(round(-TABLE_LO[0] * PX_PER_M))
    r0 = int(round(-TABLE_LO[1] * PX_PER_M))
    tex[r0:r0 + bh, c0:c0 + bw] = printed[..., None]
    return tex


def render_frame(texture: np.ndarray, world_from_camera: np.ndarray,
                 K: np.ndarray, size: tuple[int, int] = SIZE) -> np.ndarray:
    """The table seen from ``world_from_camera`` (OpenCV axes): ``(H, W, 3)`` uint8, the
    homography of the module docstring applied at 2× and box-filtered to ``size``."""
    w, h = size
    cam_from_board = np.linalg.inv(world_from_camera) @ WORLD_FROM_BOARD
    tex_to_board = np.array([[1 / PX_PER_M, 0, TABLE_LO[0]], [0, 1 / PX_PER_M, TABLE_LO[1]],
                             [0, 0, 1]])
    k2 = np.diag([2.0, 2.0, 1.0]) @ K
    k2[:2, 2] += 0.5  # OpenCV pixel centres: x2 = 2·x + 0.5
    hom = k2 @ cam_from_board[:3, [0, 1, 3]] @ tex_to_board
    big = cv2.warpPerspective(texture, hom, (2 * w, 2 * h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=WALL)
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)


def frames(n: int = FRAMES, size: tuple[int, int] = SIZE) -> tuple[list[np.ndarray],
                                                                    list[np.ndarray]]:
    """(frames, true poses) of the orbit: uint8 RGB frames and ``world_from_camera``."""
    tex = table_texture()
    K = intrinsics(size)
    poses = orbit(n)
    return [render_frame(tex, p, K, size) for p in poses], poses


SCENE_HEADER = """\
# arlight live example: the AR scene of marker_orbit.mp4 (written by
# arlight.live.marker_video.write_bundle; the world frame is the printed board's, +Y up).
# The camera pose is the first frame's; `arlight live` tracks it on the board every frame.
"""


def scene_dict(model: str) -> dict:
    """The AR scene of the bundled example: camera (``K``, sRGB), the table as a real
    diffuse rectangle, a virtual bunny on the board's centre, a sun and a uniform sky."""
    from arlight.camera_response import srgb_decode
    from arlight.insert.proxy import plane_shape

    K = intrinsics()
    w, h = SIZE
    c = board_centre()
    wood = srgb_decode(np.asarray(WOOD) / 255.0).round(4).tolist()
    return {
        "format": "arlight-scene/1",
        "camera": {"resolution": [w, h], "transfer": "srgb",
                   "intrinsics": {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2] + 0.5,
                                  "cy": K[1, 2] + 0.5},
                   "world_from_camera": orbit(1)[0].tolist()},
        "shapes": [{**plane_shape(TABLE_LO, TABLE_HI, {"type": "diffuse", "albedo": wood}),
                    "name": "table"},
                   {"name": "bunny", "role": "virtual", "type": "mesh", "file": model,
                    "transform": {"scale": 0.7, "rotate": [0.0, 1.0, 0.0, 30.0],
                                  "translate": [float(c[0]), 0.0, float(c[2])]},
                    "material": {"type": "diffuse", "albedo": [0.6, 0.58, 0.55]}}],
        "lights": [{"type": "directional", "direction": [0.45, -0.8, -0.4],
                    "irradiance": [1.6, 1.55, 1.5]},
                   {"type": "constant", "radiance": [0.3, 0.32, 0.36]}],
    }


def write_bundle(folder: str | Path, n: int = FRAMES) -> dict[str, Path]:
    """Write ``marker_orbit.mp4`` (``n`` frames at :data:`FPS`), ``calibration.json`` and
    ``scene.toml`` into ``folder``; returns their paths."""
    from arlight.sequence.video import encode

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    imgs, _ = frames(n)
    video = encode(folder / "marker_orbit.mp4", imgs, FPS)
    calib = folder / "calibration.json"
    calib.write_text(json.dumps({"K": intrinsics().tolist(), "dist": [0.0] * 5,
                                 "size": list(SIZE)}, indent=1) + "\n")
    from arlight.scene.save import to_toml

    scene = folder / "scene.toml"
    d = scene_dict("../demo/bunny.ply")
    scene.write_text(SCENE_HEADER + to_toml(d))
    return {"video": video, "calibration": calib, "scene": scene}


__all__ = ["FPS", "MARKER", "frames", "intrinsics", "orbit", "render_frame", "scene_dict",
           "table_texture", "write_bundle"]
