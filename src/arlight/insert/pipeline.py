"""``arlight insert``: from a photo with a printed marker to an editable scene and a composite.

Steps (``docs/insert.md``): read the photo; register the camera on the marker
(:mod:`arlight.insert.registration`); undistort the photo into the scene's pinhole camera;
build the proxy (the board's plane, optional boxes, :mod:`arlight.insert.proxy`) and the
light (:mod:`arlight.insert.lighting`); estimate the plane's albedo
(:mod:`arlight.insert.albedo`); place the virtual object; validate the whole scene with the
scene loader; render with any registered method; write the scene file
(:func:`arlight.scene.save.save_scene`), the layers and the composite
(:func:`arlight.layer_files.write_layers`) as one output set.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.insert.albedo import AlbedoEstimate, PlaneRegion, estimate_albedo
from arlight.insert.proxy import ProxyBox, plane_shape
from arlight.insert.registration import (
    Calibration,
    MarkerSpec,
    Registration,
    load_calibration,
    parse_marker,
    register,
    undistort,
)
from arlight.scene.model import ARScene

INSERT_FILES = ("scene.toml", "scene.frame.png", "scene.frame.exr", "albedo.png",
                "registration.json", "render")
"""Names an ``arlight insert`` output folder holds (an existing folder of only these may be
replaced)."""

SATURATED = 0.98
"""Code values at or above this fraction of the maximum are treated as clipped (no albedo
from them)."""


@dataclass
class InsertRequest:
    """Everything ``arlight insert`` needs (CLI flags of the same names).

    Attributes:
        photo: the photograph (PNG/JPEG decoded through ``transfer``, or EXR/.hdr linear).
        calib: calibration file (OpenCV YAML/XML or JSON) or a :class:`Calibration`.
        marker: target description (:func:`parse_marker`) or a :class:`MarkerSpec`.
        light: ``--light`` value (:func:`arlight.insert.lighting.light_tables`).
        object: mesh file (PLY/OBJ/...) of the virtual object, or a glTF/GLB, USD/USDZ model
            (with its own PBR materials; ``color`` is then not used).
        at: where the bottom centre of the object's bounding box goes (m, board frame,
            +Y up; ``Y = 0`` stands on the board).
        scale: uniform scale of the mesh.
        rotate: rotations ``[(ax, ay, az, angle_deg), ...]`` applied after scaling.
        color: the object's diffuse albedo (RGB in [0, 1]).
        light_rotation_deg, light_scale: see :func:`light_tables`.
        plane_size: (X, Z) extent of the supporting plane (m), centred on the target.
        boxes: extra real boxes (:class:`ProxyBox`, board frame).
        albedo_mode: ``"texture"`` or ``"median"`` (:mod:`arlight.insert.albedo`).
        transfer: the photo's transfer function (``srgb``, ``gamma``, ``linear``).
    """

    photo: Path
    calib: Path | Calibration
    marker: str | MarkerSpec
    light: str
    object: Path
    at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0
    rotate: Sequence[tuple[float, float, float, float]] = ()
    color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    light_rotation_deg: float = 0.0
    light_scale: float = 1.0
    plane_size: tuple[float, float] = (1.0, 1.0)
    boxes: Sequence[ProxyBox] = field(default_factory=tuple)
    albedo_mode: str = "texture"
    transfer: str = "srgb"


@dataclass
class InsertResult:
    """The scene built from a photo and what was measured on the way."""

    scene: ARScene
    registration: Registration
    albedo: AlbedoEstimate
    marker: MarkerSpec
    calibration: Calibration

    def report(self) -> dict[str, Any]:
        """JSON-ready summary (``registration.json`` of an output folder)."""
        return {**self.registration.summary(),
                "albedo_median": self.albedo.median.tolist(),
                "albedo_pixels": self.albedo.pixels,
                "albedo_texel_m": self.albedo.texel,
                "marker": {"kind": self.marker.kind, "squares": list(self.marker.squares),
                           "square_length": self.marker.square_length,
                           "marker_length": self.marker.marker_length,
                           "dictionary": self.marker.dictionary},
                "calibration": self.calibration.source}


def _read_photo(path: Path, transfer: str) -> tuple[np.ndarray, np.ndarray | None,
                                                    np.ndarray]:
    """(linear radiance, code values or None for HDR, 8-bit image for the detector)."""
    from arlight.camera_response import Transfer
    from arlight.io.images import is_hdr_path, read_hdr, read_ldr

    t = Transfer(kind=transfer)  # type: ignore[arg-type]
    if is_hdr_path(path):
        lin = read_hdr(path)
        return lin, None, t.to_display(lin)
    codes = read_ldr(path)
    eight = codes if codes.dtype == np.uint8 else (codes >> 8).astype(np.uint8)
    return t.to_radiance(codes).astype(np.float32), codes, eight


def _object_shape(req: InsertRequest) -> tuple[dict[str, Any], np.ndarray]:
    """The virtual object's scene table with its bounding box's bottom centre at ``at``,
    and that transform (4×4)."""
    import trimesh

    from arlight.scene.load import transform_matrix
    from arlight.scene.models import is_model_path, read_model
    from arlight.scene.schema import Validator

    path = Path(req.object)
    if not path.is_file():
        raise InputError("mesh file not found", file=str(path), field="--object")
    model = is_model_path(path)
    if model:  # glTF/GLB, USD/USDZ: the file's own PBR materials (--color not used)
        verts = np.concatenate([p.vertices for p in read_model(path).parts])
    else:
        try:
            mesh = trimesh.load(path, force="mesh")
            verts = np.asarray(mesh.vertices, np.float64)
        except Exception as exc:  # trimesh raises many types for garbage files
            raise InputError(f"cannot read the mesh ({exc})", file=str(path),
                             field="--object") from exc
    if len(verts) == 0:
        raise InputError("the mesh has no vertices", file=str(path), field="--object")
    rot = [list(map(float, r)) for r in req.rotate]
    v = Validator("--object", Path.cwd())
    m = transform_matrix(v, {"scale": float(req.scale), "rotate": rot}, "--rotate")
    posed = verts @ m[:3, :3].T
    lo, hi = posed.min(axis=0), posed.max(axis=0)
    bottom = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    translate = np.asarray(req.at, np.float64) - bottom
    table = {"name": "object", "role": "virtual", "type": "model" if model else "mesh",
             "file": str(path.resolve()),
             "transform": {"scale": float(req.scale), "rotate": rot,
                           "translate": translate.tolist()}}
    if not model:
        table["material"] = {"type": "diffuse", "albedo": list(map(float, req.color))}
    return table, m


def _check_request(req: InsertRequest) -> None:
    """Every number of the request finite and in range (InputError naming the option)."""
    from arlight.insert.numbers import MAX_ANGLE_DEG, MAX_LENGTH_M, number

    at = np.asarray(req.at, np.float64)
    if at.shape != (3,) or not np.all(np.isfinite(at)) or np.any(np.abs(at) > MAX_LENGTH_M):
        raise InputError(f"expected three finite coordinates (m), got {req.at!r}", field="--at")
    if at[1] < -1e-6:
        raise InputError(f"the object's bottom would be {-at[1] * 1000:.1f} mm below the "
                         "supporting plane (Y = 0 is the board's surface, +Y up); give Y >= 0",
                         field="--at")
    if not (np.isfinite(req.scale) and 1e-6 <= req.scale <= 1e6):
        raise InputError(f"must be in [1e-6, 1e6], got {req.scale}", field="--scale")
    for r in req.rotate:
        a = np.asarray(r, np.float64)
        if a.shape != (4,) or not np.all(np.isfinite(a)) or not np.any(a[:3]) \
                or abs(a[3]) > MAX_ANGLE_DEG or np.any(np.abs(a[:3]) > 1e6):
            raise InputError(f"expected a non-zero finite axis and an angle within "
                             f"±{MAX_ANGLE_DEG:g}°, got {tuple(r)!r}", field="--rotate")
    ps = np.asarray(req.plane_size, np.float64)
    if ps.shape != (2,) or not np.all(np.isfinite(ps)) or np.any(ps <= 0) \
            or np.any(ps > MAX_LENGTH_M):
        raise InputError(f"expected two positive lengths (m), got {req.plane_size!r}",
                         field="--plane-size")
    c = np.asarray(req.color, np.float64)
    if c.shape != (3,) or not np.all((c >= 0) & (c <= 1)):
        raise InputError(f"expected three values in [0, 1], got {req.color!r}", field="--color")
    number(req.light_rotation_deg, "--light-rotation", -MAX_ANGLE_DEG, MAX_ANGLE_DEG)
    number(req.light_scale, "--light-scale", 0.0, 1e9, lo_open=True)


def insert_inputs(req: InsertRequest, lights: Sequence[dict] = ()) -> list[Path]:
    """Every file the request reads: the photo, calibration, mesh, a light or marker file,
    and the files those reference (``lights``: the light tables, whose ``file`` entries are
    an environment map a light estimate points to)."""
    files = [Path(req.photo), Path(req.object)]
    if not isinstance(req.calib, Calibration):
        files.append(Path(req.calib))
    if isinstance(req.marker, str) and req.marker.lower().endswith(".toml"):
        files.append(Path(req.marker))
    if not req.light.lower().startswith("sun:"):
        files.append(Path(req.light))
        if req.light.lower().endswith(".json"):  # a light estimate's HDR map next to it
            try:
                d = json.loads(Path(req.light).read_text(encoding="utf-8"))
                files.append(Path(req.light).parent / d["hdr_map"]["file"])
            except (OSError, ValueError, KeyError, TypeError):
                pass
    files += [Path(t["file"]) for t in lights if isinstance(t.get("file"), str)]
    return files


def check_insert_output(out: str | Path, inputs: Sequence[Path],
                        expected_bytes: int = 0) -> Path:
    """Refuse, before any work, an output folder that is an input, holds one, or cannot be
    written as a new set (:func:`arlight.staged_output.check_output_dir`); the message names
    the output and the input."""
    import os

    from arlight.staged_output import check_output_dir

    real = Path(os.path.realpath(out))
    for p in inputs:
        if Path(os.path.realpath(p)) == real:
            raise InputError(f"is the input {p}; the output folder would replace it (choose "
                             "another output folder)", file=str(out), field="--out")
    return check_output_dir(out, INSERT_FILES, expected_bytes, inputs)


def prepare_inputs(req: InsertRequest) -> tuple[MarkerSpec, Calibration, list[dict]]:
    """Parse the cheap inputs (marker, calibration, light, object placement) so that a bad
    one fails before any image work."""
    from arlight.insert.lighting import light_tables

    _check_request(req)
    marker = req.marker if isinstance(req.marker, MarkerSpec) else parse_marker(req.marker)
    calib = req.calib if isinstance(req.calib, Calibration) else load_calibration(req.calib)
    lights = light_tables(req.light, req.light_rotation_deg, req.light_scale)
    return marker, calib, lights


def build_scene(req: InsertRequest, folder: str | Path) -> InsertResult:
    """Register, build the proxy and light, estimate the albedo and place the object.

    ``folder`` receives the albedo texture (``albedo.png``, 8-bit sRGB) when
    ``albedo_mode == "texture"``; the scene refers to it. Raises :class:`InputError` naming
    the file and field for any bad input."""
    from arlight.camera_response import Transfer
    from arlight.io.images import write_png
    from arlight.scene.load import parse_scene
    from arlight.scene.model import Light

    folder = Path(folder)
    marker, calib, light_tabs = prepare_inputs(req)
    photo = str(req.photo)
    lin, codes, eight = _read_photo(Path(req.photo), req.transfer)
    h, w = lin.shape[:2]
    calib.check_size(w, h, photo)
    reg = register(eight, calib, marker, photo)
    K = calib.K
    camera_tab = {"resolution": [w, h],
                  "intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                                 "cx": float(K[0, 2]) + 0.5, "cy": float(K[1, 2]) + 0.5},
                  "world_from_camera": reg.world_from_camera.tolist(),
                  "transfer": req.transfer}
    obj_tab, _ = _object_shape(req)
    tc = marker.centre_world()
    half = np.asarray(req.plane_size, np.float64) / 2
    outline = marker.outline_world()
    region = PlaneRegion(lo=(tc[0] - half[0], tc[2] - half[1]),
                         hi=(tc[0] + half[0], tc[2] + half[1]),
                         target_lo=(outline[:, 0].min(), outline[:, 2].min()),
                         target_hi=(outline[:, 0].max(), outline[:, 2].max()))
    # the scene without the proxy's albedo first: camera and lights validated by the loader
    data = {"camera": camera_tab, "shapes": [obj_tab], "lights": light_tabs,
            "description": f"arlight insert of {Path(photo).name}"}
    base = parse_scene(data, folder, file="<insert>")
    if codes is not None:
        frame_codes = undistort(codes, calib)
        frame = Transfer(kind=req.transfer).to_radiance(frame_codes).astype(np.float32)  # type: ignore[arg-type]
        top = np.iinfo(codes.dtype).max
        valid = frame_codes.max(axis=2) < SATURATED * top
    else:
        frame_codes = None
        frame = undistort(lin, calib).astype(np.float32)
        valid = None
    lights: list[Light] = base.lights
    alb = estimate_albedo(frame, base.camera, lights, region, valid, req.albedo_mode, photo)
    material: dict[str, Any] = {"type": "diffuse", "albedo": alb.median.tolist()}
    if alb.texture is not None:
        t = Transfer(kind="srgb")
        write_png(folder / "albedo.png", t.to_display(alb.texture))
        material = {"type": "diffuse", "texture": "albedo.png"}
    shapes = [plane_shape(region.lo, region.hi, material),
              *[b.table(i, alb.median) for i, b in enumerate(req.boxes)], obj_tab]
    data["shapes"] = shapes
    scene = parse_scene(data, folder, file="<insert>").with_frame(frame, frame_codes)
    return InsertResult(scene=scene, registration=reg, albedo=alb, marker=marker,
                        calibration=calib)


def write_insert(result: InsertResult, layers, out: str | Path, staging: Path) -> None:
    """Write the scene file, the registration report and the layers into ``staging`` (the
    staging folder of ``out``'s output set)."""
    from arlight.layer_files import write_layers
    from arlight.scene.save import save_scene

    save_scene(result.scene, staging / "scene.toml")
    (staging / "registration.json").write_text(json.dumps(result.report(), indent=2))
    write_layers(layers, result.scene, staging / "render")


def run_insert(req: InsertRequest, out: str | Path, method: str = "reference",
               settings=None) -> tuple[InsertResult, Any]:
    """Build the scene, render it with ``method`` and write ``out`` as one output set:
    ``scene.toml`` (+ ``scene.frame.png``/``.exr``, ``albedo.png``), ``registration.json``
    and ``render/`` (the layers, ``composite.png``, ``stats.json``).

    The scene file gets a ``[render]`` table with ``method`` and ``settings``, so
    ``arlight render OUT/scene.toml`` renders it the same way. Returns the
    :class:`InsertResult` and the method's layers."""
    from arlight.methods import RenderSettings, get_method
    from arlight.staged_output import StagedOutput

    settings = settings or RenderSettings()
    fn = get_method(method)
    fn.spec.parse_options(settings.options)
    _, _, lights = prepare_inputs(req)  # bad inputs fail before the output folder is touched
    check_insert_output(out, insert_inputs(req, lights))
    with StagedOutput(out, "insert", INSERT_FILES) as tmp:
        result = build_scene(req, tmp)
        # the scene file re-renders the way it was rendered (`arlight render` reads this)
        result.scene.raw["render"] = {"method": method, "spp": settings.spp,
                                      "max_depth": settings.max_depth, "seed": settings.seed,
                                      "options": dict(settings.options)}
        layers = fn(result.scene, settings)
        write_insert(result, layers, out, tmp)
    return result, layers
