"""Field definitions of the scene file format and the validators that read them.

Each table below is the reference for one kind of entry; ``docs/scene-format.md`` is written
from these tables by :func:`schema_markdown`. Validators return canonical Python values
(floats, lists of three floats, absolute paths) and raise :class:`InputError` naming the
scene file and the field path (``shapes[2].material.albedo``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arlight.bounds import MAX_SEED, MAX_SPP
from arlight.errors import InputError

REQUIRED = object()


@dataclass(frozen=True)
class Field:
    """One field of a table.

    ``kind`` is one of: ``rgb`` (a number or three numbers), ``float``, ``int``, ``bool``,
    ``str``, ``vec2``, ``vec3``, ``mat4`` (4×4 nested list), ``path`` (relative to the scene
    file), ``choice`` (one of ``choices``), ``rgb_list`` (list of RGB triples), ``table``.
    """

    kind: str
    default: Any = REQUIRED
    doc: str = ""
    unit: str = ""
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] = ()
    exclusive_min: bool = False


_RGB_REFL = dict(min=0.0, max=1.0)

MAX_LENGTH = 1.0e6
"""Largest length or coordinate a scene may hold, metres (1000 km): beyond it float32
geometry loses the precision rendering needs, and objects silently vanish."""
MAX_SCALE = 1.0e6
"""Largest magnitude of a transform's scale factors and matrix entries (smallest: 1e-6)."""
_POS = dict(min=-MAX_LENGTH, max=MAX_LENGTH)  # coordinates, metres
_LEN = dict(min=0.0, max=MAX_LENGTH, exclusive_min=True)  # positive lengths, metres
_TWO_SIDED = Field("bool", True, "both sides reflect (false: the back side is black, as "
                   "Mitsuba's BSDFs without `twosided`)")

MATERIAL_TYPES: dict[str, dict[str, Field]] = {
    "diffuse": {
        "albedo": Field("rgb", 0.5, "Lambertian reflectance", "", **_RGB_REFL),
        "texture": Field("path", None, "albedo texture; LDR files are sRGB-decoded, HDR files "
                         "are linear; replaces `albedo` (needs UVs); decoded on load"),
        "two_sided": _TWO_SIDED,
    },
    "phong": {
        "kd": Field("rgb", 0.5, "diffuse reflectivity k_d (Kán Eq. 2.6)", "", **_RGB_REFL),
        "ks": Field("rgb", 0.0, "specular reflectivity k_s; k_d + k_s <= 1 per channel", "",
                    **_RGB_REFL),
        "exponent": Field("float", 20.0, "Phong shininess n", "", min=0.0, max=1e6),
        "two_sided": _TWO_SIDED,
    },
    "roughconductor": {
        "alpha": Field("float", 0.1, "GGX roughness α", "", min=1e-4, max=1.0),
        "reflectance": Field("rgb", 0.9, "constant (Fresnel) reflectance", "", **_RGB_REFL),
        "two_sided": _TWO_SIDED,
    },
    "roughdielectric": {
        "alpha": Field("float", 0.1, "GGX roughness α", "", min=1e-4, max=1.0),
        "ior": Field("float", 1.5, "interior index of refraction", "", min=1e-3,
                     exclusive_min=True, max=100.0),
        "ext_ior": Field("float", 1.0, "exterior index of refraction (Mitsuba's default is "
                         "air, 1.000277; ours is vacuum)", "", min=1e-3, max=100.0),
    },
    "mirror": {
        "reflectance": Field("rgb", 1.0, "perfect specular reflectance", "", **_RGB_REFL),
        "two_sided": _TWO_SIDED,
    },
    "glass": {
        "ior": Field("float", 1.5, "index of refraction of a smooth dielectric (1 = "
                     "invisible)", "", min=1e-3, max=100.0),
        "ext_ior": Field("float", 1.0, "exterior index of refraction (Mitsuba's default is "
                         "air, 1.000277; ours is vacuum)", "", min=1e-3, max=100.0),
    },
    "pbr": {
        "base_color": Field("rgb", 1.0, "base colour factor (glTF `baseColorFactor`, linear)",
                            "", **_RGB_REFL),
        "base_color_texture": Field("path", None, "base colour texture (PNG/JPEG, sRGB-decoded; "
                                    "an alpha channel multiplies `alpha`); times `base_color`"),
        "metallic": Field("float", 1.0, "metalness factor (glTF `metallicFactor`)", "",
                          min=0.0, max=1.0),
        "roughness": Field("float", 1.0, "perceptual roughness factor (glTF "
                           "`roughnessFactor`; GGX α = roughness²)", "", min=0.0, max=1.0),
        "metallic_roughness_texture": Field("path", None, "linear texture: G = roughness, "
                                            "B = metallic (glTF's channels); times the factors"),
        "normal_texture": Field("path", None, "tangent-space normal map (linear, n = 2·rgb − 1, "
                                "+Y up as glTF/OpenGL)"),
        "normal_scale": Field("float", 1.0, "scale of the normal map's x and y", "",
                              min=0.0, max=10.0),
        "occlusion_texture": Field("path", None, "ambient occlusion (R channel; read by the "
                                   "real-time approximations, ignored by path tracers, which "
                                   "trace occlusion)"),
        "occlusion_strength": Field("float", 1.0, "occlusion = 1 + strength · (R − 1)", "",
                                    min=0.0, max=1.0),
        "emissive": Field("rgb", 0.0, "emitted radiance factor", "W/(sr·m²)", min=0.0,
                          max=1e6),
        "emissive_texture": Field("path", None, "emission texture (sRGB-decoded); times "
                                  "`emissive`"),
        "alpha": Field("float", 1.0, "opacity factor (glTF base colour alpha, USD `opacity`)",
                       "", min=0.0, max=1.0),
        "alpha_mode": Field("choice", "opaque", "`opaque` (alpha ignored), `mask` (opaque where "
                            "alpha >= `alpha_cutoff`, else absent), `blend` (alpha-weighted "
                            "coverage)", choices=("opaque", "mask", "blend")),
        "alpha_cutoff": Field("float", 0.5, "threshold of `alpha_mode = \"mask\"`", "",
                              min=0.0, max=1.0),
        "ior": Field("float", 1.5, "index of refraction of the dielectric part "
                     "(`KHR_materials_ior`, USD `ior`)", "", min=1.0, max=10.0),
        "transmission": Field("float", 0.0, "fraction of light transmitted through the "
                              "dielectric part (`KHR_materials_transmission`)", "", min=0.0,
                              max=1.0),
        "two_sided": Field("bool", True, "both sides reflect (glTF `doubleSided = false` "
                           "gives false; ignored when `transmission` > 0)"),
    },
}

SHAPE_TYPES: dict[str, dict[str, Field]] = {
    "rectangle": {
        "size": Field("vec2", [1.0, 1.0], "full side lengths along local x and y (Mitsuba's "
                      "`rectangle` spans [-1, 1]²: half-size 1)", "m", **_LEN),
        "normal": Field("vec3", [0.0, 0.0, 1.0], "front normal before `transform` (the local "
                        "+z axis is turned onto it)"),
    },
    "disk": {
        "radius": Field("float", 0.5, "radius", "m", **_LEN),
        "normal": Field("vec3", [0.0, 0.0, 1.0], "front normal before `transform`"),
    },
    "box": {
        "size": Field("vec3", [1.0, 1.0, 1.0], "full side lengths along local x, y, z, centred "
                      "on the origin (Mitsuba's `cube` spans [-1, 1]³)", "m", **_LEN),
    },
    "sphere": {
        "radius": Field("float", 0.5, "radius (centred on the origin; Mitsuba's `center` "
                        "becomes `transform.translate`)", "m", **_LEN),
    },
    "mesh": {
        "file": Field("path", REQUIRED, "PLY, OBJ, glTF/GLB, STL or OFF file (read by "
                      "trimesh, geometry only: `type = \"model\"` reads glTF and USD files "
                      "with their materials)"),
        "normals": Field("choice", "auto", "shading normals: `file` (the vertex normals stored "
                         "in a PLY/OBJ file; an error if it has none), `recompute` (smooth, "
                         "angle-weighted, welded across split vertices), `flat` (face normals); "
                         "`auto`: `file` when the file has normals, else `recompute`",
                         choices=("auto", "file", "recompute", "flat")),
        "smooth": Field("bool", True, "older form: `false` is `normals = \"flat\"`; `true` "
                        "leaves `normals` in charge"),
    },
    "model": {
        "file": Field("path", REQUIRED, "glTF 2.0 (`.gltf`, `.glb`) or USD (`.usd`, `.usda`, "
                      "`.usdc`, `.usdz`) file; expands on load into one mesh shape per "
                      "mesh primitive (glTF) or Mesh prim (USD), named `<name>/<part>`, with "
                      "the file's `pbr` materials"),
        "select": Field("str", None, "only this node (glTF node name) or prim path (USD) and "
                        "what lies below it (default: the whole default scene)"),
    },
}

EXPANDED_SHAPE_TYPES = ("model",)
"""Shape types that expand into other shapes on load (a model into its ``mesh`` parts):
they never reach a renderer."""

SHAPE_COMMON: dict[str, Field] = {
    "name": Field("str", None, "unique name (default: `shape<i>`)"),
    "role": Field("choice", REQUIRED, "`real` (proxy of the real world) or `virtual`",
                  choices=("real", "virtual")),
    "type": Field("choice", REQUIRED, "shape type", choices=tuple(SHAPE_TYPES)),
    "material": Field("table", "default", "name of an entry of [materials] or an inline table"),
    "transform": Field("table", None, "object-to-world transform, see Transforms"),
}

TRANSFORM_FIELDS: dict[str, Field] = {
    "scale": Field("vec3", [1.0, 1.0, 1.0], "scale (a number or three), applied first; "
                   "1e-6 <= abs <= 1e6", min=-MAX_SCALE, max=MAX_SCALE),
    "rotate": Field("table", [], "rotations after scaling, applied in list order: "
                    "`[ax, ay, az, angle_deg]` or `{axis = [ax, ay, az], angle = deg}`, one "
                    "or a list; right-handed: counter-clockwise looking down the axis towards "
                    "the origin (as Mitsuba's `rotate`)", "deg"),
    "translate": Field("vec3", [0.0, 0.0, 0.0], "translation, applied last", "m", **_POS),
    "matrix": Field("mat4", None, "full 4×4 object-to-world matrix (excludes the others; "
                    "entries within ±1e6)", min=-MAX_SCALE, max=MAX_SCALE),
}

LIGHT_TYPES: dict[str, dict[str, Field]] = {
    "envmap": {
        "file": Field("path", REQUIRED, "HDR image (EXR or Radiance .hdr), linear radiance; "
                      "decoded and checked on load"),
        "mapping": Field("choice", "equirect", "`equirect` (latitude-longitude, width = 2 × "
                         "height) or `angular` (Debevec light probe, square)",
                         choices=("equirect", "angular")),
        "scale": Field("float", 1.0, "radiance multiplier", "", min=0.0, max=1e12),
        "rotation_deg": Field("float", 0.0, "rotation of the map about world +Y, right-handed "
                              "(counter-clockwise seen from above): Mitsuba's `to_world = "
                              "rotate(0, 1, 0, angle)`", "deg", min=-1e6, max=1e6),
    },
    "sh": {
        "coefficients": Field("rgb_list", REQUIRED, "real SH coefficients of radiance, "
                              "(L+1)² RGB rows, index l(l+1)+m", "W/(sr·m²)"),
        "scale": Field("float", 1.0, "radiance multiplier", "", min=0.0, max=1e12),
        "rotation_deg": Field("float", 0.0, "rotation about world +Y, as for `envmap`", "deg",
                              min=-1e6, max=1e6),
        "resolution": Field("int", 64, "height of the equirect map the SH is rendered into",
                            "px", min=4, max=4096),
    },
    "constant": {
        "radiance": Field("rgb", REQUIRED, "radiance of a uniform environment", "W/(sr·m²)",
                          min=0.0),
    },
    "point": {
        "position": Field("vec3", REQUIRED, "position", "m", **_POS),
        "intensity": Field("rgb", REQUIRED, "radiant intensity", "W/sr", min=0.0),
    },
    "spot": {
        "position": Field("vec3", REQUIRED, "position", "m", **_POS),
        "target": Field("vec3", REQUIRED, "point the spot is aimed at", "m", **_POS),
        "intensity": Field("rgb", REQUIRED, "radiant intensity on the axis", "W/sr", min=0.0),
        "cutoff_deg": Field("float", 20.0, "half angle where the light ends", "deg", min=0.0,
                            max=90.0, exclusive_min=True),
        "beam_width_deg": Field("float", 15.0, "half angle where the fall-off starts", "deg",
                                min=0.0, max=90.0),
    },
    "directional": {
        "direction": Field("vec3", REQUIRED, "direction the light travels (towards the scene)"),
        "irradiance": Field("rgb", REQUIRED, "irradiance on a surface facing the light",
                            "W/m²", min=0.0),
    },
    "area": {
        "size": Field("vec2", [1.0, 1.0], "full rectangle side lengths", "m", **_LEN),
        "normal": Field("vec3", [0.0, 0.0, 1.0], "emitting side's normal before `transform`"),
        "transform": Field("table", None, "placement, see Transforms"),
        "radiance": Field("rgb", REQUIRED, "emitted radiance (front side)", "W/(sr·m²)",
                          min=0.0),
    },
    "sphere": {
        "position": Field("vec3", REQUIRED, "centre", "m", **_POS),
        "radius": Field("float", REQUIRED, "radius of the emitting sphere (a small bulb; a "
                        "point light's physical stand-in, e.g. for caustic ground truth)", "m",
                        **_LEN),
        "intensity": Field("rgb", REQUIRED, "radiant intensity in every direction; the "
                           "surface radiance is intensity / (π radius²)", "W/sr", min=0.0),
    },
}

CAMERA_FIELDS: dict[str, Field] = {
    "resolution": Field("vec2", REQUIRED, "[width, height]", "px"),
    "fov_y_deg": Field("float", None, "vertical field of view (or give `intrinsics`)", "deg",
                       min=0.0, max=179.0, exclusive_min=True),
    "intrinsics": Field("table", None, "OpenCV `{fx, fy, cx, cy}` in pixels"),
    "look_at": Field("table", None, "`{origin, target, up}` (or give `world_from_camera`)"),
    "world_from_camera": Field("mat4", None, "4×4 camera-to-world pose, OpenCV axes", "m",
                               **_POS),
    "aperture_radius": Field("float", 0.0, "thin-lens aperture radius (0 = pinhole)", "m",
                             min=0.0, max=1e3),
    "focus_distance": Field("float", 1.0, "distance of the focal plane along the view axis",
                            "m", **_LEN),
    "aperture_shape": Field("choice", "disk", "`disk` or Kán's `square`",
                            choices=("disk", "square")),
    "transfer": Field("choice", "srgb", "frame transfer function",
                      choices=("srgb", "gamma", "linear")),
    "gamma": Field("float", 2.2, "exponent for `transfer = \"gamma\"`", "", min=0.0,
                   exclusive_min=True, max=10.0),
    "exposure": Field("float", 0.0, "display = transfer(radiance · 2^exposure)", "EV",
                      min=-64.0, max=64.0),
}

FRAME_FIELDS: dict[str, Field] = {
    "image": Field("path", None, "LDR (PNG/JPEG, decoded through the camera's transfer "
                   "function) or HDR (EXR/.hdr, linear radiance) image of the camera's size"),
    "depth": Field("path", None, "depth image of the camera's size (single-channel EXR or a "
                   "2-D `.npy`), distance along the camera's +z axis; NaN or 0 = unknown", "m"),
    "timestamp": Field("float", None, "capture time of the frame", "s"),
    "object_transforms": Field("table", {}, "per-frame pose of named shapes: `{name = "
                               "transform}` (see Transforms), applied on the left of the "
                               "shape's own transform (a world-space motion)"),
}


RENDER_FIELDS: dict[str, Field] = {
    "method": Field("str", None, "method to render with (`arlight methods`; default "
                    "`reference`)"),
    "spp": Field("int", None, "samples per pixel (default 64)", "", min=1, max=MAX_SPP),
    "max_depth": Field("int", None, "longest path in vertices, Mitsuba's convention (2 = "
                       "direct light only, -1 = unlimited; default 8)", "", min=-1, max=1024),
    "seed": Field("int", None, "random seed (default 0)", "", min=0, max=MAX_SEED),
    "options": Field("table", {}, "method options `{key = value}` (`arlight methods NAME`); "
                     "checked against the method when rendering"),
}
"""The optional ``[render]`` table: how the scene is meant to be rendered. Command-line
flags given explicitly override these; absent ones fall back to the defaults shown."""


class Validator:
    """Reads fields of one scene file, raising errors that name the file and field."""

    def __init__(self, file: str, base_dir: Path):
        self.file = file
        self.base_dir = base_dir

    def fail(self, field: str, message: str) -> InputError:
        return InputError(message, file=self.file, field=field)

    def table(self, value: Any, field: str) -> dict:
        if not isinstance(value, dict):
            raise self.fail(field, f"expected a table, got {type(value).__name__}")
        return value

    def check_keys(self, table: dict, allowed: set[str], field: str) -> None:
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.fail(f"{field}.{unknown[0]}" if field else unknown[0],
                            f"unknown field; expected one of {', '.join(sorted(allowed))}")

    def number(self, value: Any, field: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(field, f"expected a number, got {value!r}")
        if not math.isfinite(value):
            raise self.fail(field, f"must be finite, got {value!r}")
        return float(value)

    def _range(self, x: float, spec: Field, field: str) -> None:
        if spec.min is not None and (x < spec.min or (spec.exclusive_min and x == spec.min)):
            rel = ">" if spec.exclusive_min else ">="
            raise self.fail(field, f"must be {rel} {spec.min}, got {x}")
        if spec.max is not None and x > spec.max:
            raise self.fail(field, f"must be <= {spec.max}, got {x}")

    def vector(self, value: Any, n: int, field: str) -> list[float]:
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.fail(field, f"expected a list of {n} numbers, got {value!r}")
        return [self.number(v, f"{field}[{i}]") for i, v in enumerate(value)]

    def value(self, value: Any, spec: Field, field: str) -> Any:
        """Validate one value against its field spec and return it in canonical form."""
        k = spec.kind
        if k in ("float", "int"):
            x = self.number(value, field)
            if k == "int" and (not isinstance(value, int) or isinstance(value, bool)):
                raise self.fail(field, f"expected an integer, got {value!r}")
            if k == "int":
                x = int(value)  # exact, and errors print "-1", not "-1.0"
            self._range(x, spec, field)
            return x
        if k == "rgb":
            rgb = [self.number(value, field)] * 3 if not isinstance(value, list | tuple) \
                else self.vector(value, 3, field)
            for i, c in enumerate(rgb):
                if c < 0:
                    raise self.fail(field, f"negative value {c} (channel {i}) is not allowed")
                self._range(c, spec, field)
            return rgb
        if k == "rgb_list":
            if not isinstance(value, list) or not value:
                raise self.fail(field, "expected a non-empty list of [r, g, b] rows")
            return [self.vector(v, 3, f"{field}[{i}]") for i, v in enumerate(value)]
        if k in ("vec2", "vec3"):
            n = 2 if k == "vec2" else 3
            v = self.vector(value, n, field)
            for x in v:
                self._range(x, spec, field)
            return v
        if k == "mat4":
            if not isinstance(value, list) or len(value) != 4:
                raise self.fail(field, "expected a 4×4 nested list")
            m = np.array([self.vector(r, 4, f"{field}[{i}]") for i, r in enumerate(value)])
            for i, row in enumerate(m):
                for x in row:
                    self._range(float(x), spec, f"{field}[{i}]")
            return m.tolist()
        if k == "bool":
            if not isinstance(value, bool):
                raise self.fail(field, f"expected true or false, got {value!r}")
            return value
        if k == "str":
            if not isinstance(value, str) or not value:
                raise self.fail(field, f"expected a non-empty string, got {value!r}")
            return value
        if k == "choice":
            if value not in spec.choices:
                raise self.fail(field, f"unknown value {value!r}; expected one of "
                                f"{', '.join(spec.choices)}")
            return value
        if k == "path":
            if not isinstance(value, str) or not value:
                raise self.fail(field, f"expected a file path, got {value!r}")
            p = Path(value)
            p = p if p.is_absolute() else (self.base_dir / p)
            if not p.is_file():
                raise self.fail(field, f"file not found: {p}")
            return str(p.resolve())
        if k == "table":
            return value
        raise AssertionError(f"unknown field kind {k}")

    def fields(self, table: dict, specs: dict[str, Field], field: str,
               extra: set[str] = frozenset()) -> dict[str, Any]:
        """Validate a table against ``specs``; unknown keys (other than ``extra``) fail."""
        self.check_keys(table, set(specs) | set(extra), field)
        out: dict[str, Any] = {}
        for name, spec in specs.items():
            path = f"{field}.{name}" if field else name
            if name in table:
                out[name] = self.value(table[name], spec, path)
            elif spec.default is REQUIRED:
                raise self.fail(path, "missing required field")
            elif spec.default is None or spec.kind == "table":
                out[name] = copy.deepcopy(spec.default)
            else:  # defaults in the same canonical form as given values (0.5 -> [0.5] * 3)
                out[name] = self.value(spec.default, spec, path)
        return out


def field_range(spec: Field) -> str:
    """The allowed range of a numeric field as text (``(0, 1e+06]``), or "" if unbounded."""
    if spec.min is None and spec.max is None:
        return ""
    lo = "−∞" if spec.min is None else f"{spec.min:g}"
    hi = "∞" if spec.max is None else f"{spec.max:g}"
    return f"{'(' if spec.exclusive_min else '['}{lo}, {hi}{']' if spec.max is not None else ')'}"


def schema_markdown() -> str:
    """The field reference of the scene format as Markdown tables (for docs/scene-format.md)."""

    def rows(specs: dict[str, Field]) -> list[str]:
        lines = ["| field | kind | default | unit | range | meaning |",
                 "|---|---|---|---|---|---|"]
        for name, s in specs.items():
            default = "required" if s.default is REQUIRED else (
                "—" if s.default is None else f"`{s.default}`")
            kind = s.kind if not s.choices else " \\| ".join(f"`{c}`" for c in s.choices)
            lines.append(f"| `{name}` | {kind} | {default} | {s.unit} | {field_range(s)} | "
                         f"{s.doc} |")
        return lines

    out = ["## [camera]", "", *rows(CAMERA_FIELDS), "", "## [frame]", "", *rows(FRAME_FIELDS),
           "", "## [[shapes]] (common fields)", "", *rows(SHAPE_COMMON), ""]
    for name, specs in SHAPE_TYPES.items():
        out += [f"### shape `type = \"{name}\"`", "", *rows(specs), ""]
    out += ["## Transforms", "", *rows(TRANSFORM_FIELDS), ""]
    out += ["## [render]", "", *rows(RENDER_FIELDS), ""]
    for name, specs in MATERIAL_TYPES.items():
        out += [f"## material `type = \"{name}\"`", "", *rows(specs), ""]
    for name, specs in LIGHT_TYPES.items():
        out += [f"## light `type = \"{name}\"`", "", *rows(specs), ""]
    return "\n".join(out)


if __name__ == "__main__":  # regenerate the field reference of docs/scene-format.md
    print(schema_markdown())
