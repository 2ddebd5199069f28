"""Writing AR scenes as scene files (TOML), from the validated model.

:func:`save_scene` writes what :func:`arlight.scene.load.load_scene` reads back into an equal
scene: the camera as OpenCV intrinsics and a 4×4 ``world_from_camera``, every shape and area
light with its object-to-world matrix (``transform = { matrix = ... }``, so the local
``normal`` rotation is folded in), materials by name, lights with their parameters, and the
frame's images next to the file. The file is built from the model, not from the dictionary the
scene was read from, so scenes made in code (the studio, ``arlight insert``) save the same way.

Paths to meshes, textures and environment maps are written relative to the scene file's
folder when they lie below it, else absolute. The background frame is written as
``<stem>.frame.png`` (the raw code values of an LDR frame, byte for byte) or
``<stem>.frame.exr`` (linear radiance), the depth as ``<stem>.depth.exr``. Every file is
written atomically; the TOML last, so a reader never sees a scene whose frame is missing.
"""

from __future__ import annotations

import copy
import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from arlight.scene.load import FORMAT, PATH_KEYS
from arlight.scene.model import ARScene, Light, Shape
from arlight.scene.pbr import Texture

# Parameters a loader derives or folds into `transform`; they are not written back.
_DERIVED = {"normal", "transform", "to_world"}


def save_scene(scene: ARScene, path: str | Path, description: str | None = None) -> Path:
    """Write ``scene`` as a TOML scene file at ``path`` (plus its frame/depth images).

    Args:
        scene: the scene to write.
        path: the ``.toml`` file to write; its folder is created if needed.
        description: the file's one-line description (default: the one it was loaded with).

    Returns:
        The path written.
    """
    from arlight.io.images import atomic_write, write_exr, write_png

    path = Path(path)
    folder = path.parent.resolve()
    folder.mkdir(parents=True, exist_ok=True)
    data = scene_to_dict(scene, folder, description)
    frame: dict[str, Any] = {}
    if scene.frame_codes is not None:
        frame["image"] = write_png(folder / f"{path.stem}.frame.png", scene.frame_codes).name
    elif scene.frame is not None:
        frame["image"] = write_exr(folder / f"{path.stem}.frame.exr", scene.frame).name
    if scene.depth is not None:
        frame["depth"] = write_exr(folder / f"{path.stem}.depth.exr", scene.depth).name
    if scene.timestamp is not None:
        frame["timestamp"] = float(scene.timestamp)
    if frame:
        data["frame"] = frame
    with atomic_write(path, ".toml") as tmp:
        tmp.write_text(to_toml(data), encoding="utf-8")
    return path


def scene_to_dict(scene: ARScene, base_dir: str | Path,
                  description: str | None = None) -> dict[str, Any]:
    """The scene file's dictionary (without ``[frame]``); paths relative to ``base_dir``."""
    base = Path(base_dir).resolve()
    desc = description if description is not None else scene.raw.get("description")
    out: dict[str, Any] = {"format": FORMAT}
    if desc:
        out["description"] = str(desc)
    out["camera"] = _camera_dict(scene)
    materials: dict[str, dict[str, Any]] = {}
    shapes = []
    groups: set[str] = set()
    for s in scene.shapes:
        if s.group is not None:  # a model's parts: one `type = "model"` entry
            if s.group in groups:
                continue
            groups.add(s.group)
            if not s.params.get("own_material"):
                shapes.append(_model_dict(s, base))
                continue
        mat = _params(s.material.params, base, type=s.material.type)
        if materials.setdefault(s.material.name, mat) != mat:
            raise ValueError(f"two different materials are named {s.material.name!r}")
        shapes.append(_shape_dict(s, s.material.name, base))
    if materials:
        out["materials"] = materials
    out["shapes"] = shapes
    out["lights"] = [_light_dict(x, base) for x in scene.lights]
    if scene.raw.get("render"):
        out["render"] = copy.deepcopy(scene.raw["render"])
    return out


def _camera_dict(scene: ARScene) -> dict[str, Any]:
    c = scene.camera
    t = c.transfer
    return {"resolution": [c.width, c.height],
            "intrinsics": {"fx": float(c.fx), "fy": float(c.fy), "cx": float(c.cx),
                           "cy": float(c.cy)},
            "world_from_camera": _matrix(c.world_from_camera),
            "aperture_radius": float(c.aperture_radius),
            "focus_distance": float(c.focus_distance), "aperture_shape": c.aperture_shape,
            "transfer": t.kind, "gamma": float(t.gamma), "exposure": float(t.exposure)}


def _shape_dict(s: Shape, material: str, base: Path) -> dict[str, Any]:
    if s.group is not None:
        return {**_model_dict(s, base), "material": material}
    return {"name": s.name, "role": s.role, "type": s.type,
            **_params(s.params, base), "material": material,
            "transform": {"matrix": _matrix(s.to_world)}}


def _model_dict(s: Shape, base: Path) -> dict[str, Any]:
    """The ``type = "model"`` entry a model part came from (all parts share its transform;
    the file's own node transforms are applied again on load)."""
    out: dict[str, Any] = {"name": s.group, "role": s.role, "type": "model",
                           "file": _relative(Path(s.params["file"]), base)}
    if s.params.get("select") is not None:
        out["select"] = s.params["select"]
    out["transform"] = {"matrix": _matrix(s.to_world)}
    return out


def _light_dict(light: Light, base: Path) -> dict[str, Any]:
    out = {"name": light.name, "type": light.type, **_params(light.params, base)}
    if "to_world" in light.params:
        out["transform"] = {"matrix": _matrix(light.params["to_world"])}
    return out


def _params(params: dict[str, Any], base: Path, **first: Any) -> dict[str, Any]:
    """TOML-ready parameters: None dropped (TOML has no null), arrays as lists, paths
    relative to ``base`` where possible."""
    out: dict[str, Any] = dict(first)
    for k, x in params.items():
        if x is None or k in _DERIVED:
            continue
        if isinstance(x, Texture):  # a decoded texture is written as its file
            x = _relative(Path(x.source), base)
        elif k in PATH_KEYS and isinstance(x, str):
            x = _relative(Path(x), base)
        elif isinstance(x, np.ndarray):
            x = x.tolist()
        out[k] = x
    return out


def _relative(p: Path, base: Path) -> str:
    p = p.resolve()
    try:
        return p.relative_to(base).as_posix()
    except ValueError:
        return os.fspath(p)


def _matrix(m: Any) -> list[list[float]]:
    return [[float(x) for x in row] for row in np.asarray(m, dtype=np.float64)]


def to_toml(data: dict[str, Any]) -> str:
    """TOML text for a scene dictionary, laid out as people write scene files.

    Top-level values first, then one ``[table]`` per table (``[materials.<name>]`` for
    tables of tables) and one ``[[array]]`` block per table in an array; vectors and
    matrices stay on one line. Covers the value types scene files use (str, bool, int, float,
    lists, tables); non-finite floats raise ValueError (TOML scene files reject them).
    """
    lines = [f"{_key(k)} = {_value(v)}" for k, v in data.items() if not _is_section(v)]
    for k, v in data.items():
        if isinstance(v, dict):
            if v and all(isinstance(t, dict) for t in v.values()):  # [materials.wood]
                for name, table in v.items():
                    lines += ["", f"[{_key(k)}.{_key(name)}]", *_body(table)]
            else:
                lines += ["", f"[{_key(k)}]", *_body(v)]
        elif _is_section(v):
            for table in v:
                lines += ["", f"[[{_key(k)}]]", *_body(table)]
    return "\n".join(lines) + "\n"


def _is_section(v: Any) -> bool:
    return isinstance(v, dict) or (isinstance(v, list) and bool(v)
                                   and all(isinstance(x, dict) for x in v))


def _body(table: dict[str, Any]) -> list[str]:
    return [f"{_key(k)} = {_value(v)}" for k, v in table.items()]


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        if not math.isfinite(v):
            raise ValueError(f"cannot write the non-finite number {v} to a scene file")
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list | tuple | np.ndarray):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write a {type(v).__name__} to a scene file")
