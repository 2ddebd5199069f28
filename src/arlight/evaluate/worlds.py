"""Generated worlds: AR scenes nobody tuned on, drawn from a seed (issue #30).

    from arlight.evaluate.worlds import generate, split_seeds
    w = generate(1_000_003)          # a held-out world: w.world, w.proxy (scene dictionaries)
    scene = w.suite_scene(width=160) # a SuiteScene, as the evaluation harness runs it
    arlight worlds make --seed 1000003 -o DIR    # the same world as scene files + renders

A seed draws a **world** (what the camera saw: real shapes with all their detail, the virtual
objects to insert, the lights and the camera) and its **proxy** (the reconstruction a method
is given, coarser as real reconstructions are: textures lost to their mean albedo, bevelled
boxes reconstructed as sharp boxes, one surface offset by 0.5–3 % of the world's size, small
objects missing). The distribution is meant to span what users meet, not what the methods
like (:data:`CLASSES` and :func:`generate` say how each item is drawn):

* **scale**: a tabletop 0.3–1.5 m across, an indoor room 3–8 m with walls and a ceiling, an
  outdoor ground 10–50 m;
* **lights**: a bundled HDR map at a random rotation and exposure, a constant sky, or none
  (closed rooms); 0–3 local lights — rectangles and spheres from 1 cm to 2 m, points, spots —
  and a sun (``directional``) outdoors; each local light's contribution at the objects is
  drawn over three orders of magnitude relative to the environment's, and it stands behind,
  beside or in front of the camera (:func:`light_placement`);
* **materials**: diffuse (textured or plain), Phong, rough conductor, mirror, glass;
* **virtual objects**: 1–2 of the bundled meshes or primitives at a random size, yaw and
  albedo, resting on the ground or on a real object, or floating above it;
* **camera**: 640×480, field of view 35–70°, a pinhole or a thin lens (depth of field).

The camera's exposure is set from the world description (no render): ``2^exposure`` maps the
radiance of a 50 % grey diffuse surface at the objects under the estimated irradiance to 0.18
(:func:`auto_exposure`), so that display-space metrics compare worlds of any brightness.

**Splits.** Seeds below :data:`HELDOUT_BASE` are *training* worlds, seeds from it on are
*held-out* worlds (:func:`split_seeds`, :func:`split_of`). Any constant chosen by
measurement is chosen on training worlds and reported on held-out worlds (docs/testing.md).

**Determinism.** A world depends only on its seed and :data:`GENERATOR_VERSION`: the draws
come from one ``numpy.random.Generator(PCG64(seed))`` in a fixed order and every number is
rounded to 6 significant digits before it is written, so the same seed gives the same files
byte for byte on any machine. Bump :data:`GENERATOR_VERSION` when the distribution changes
(held-out numbers from different versions are not comparable).
"""

from __future__ import annotations

import copy
import math
import shutil
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError

GENERATOR_VERSION = 2
"""Changes whenever the same seed would give a different world. v2: a closed room always has
a local light (v1 drew some closed rooms lit only by a sky outside their walls: black frames,
e.g. held-out seed 1000023)."""
HELDOUT_BASE = 1_000_000
"""First held-out seed: seeds ``[0, HELDOUT_BASE)`` are training worlds, the rest held out."""
SPLITS = ("training", "heldout")
MAX_WORLDS = 10_000
"""Most worlds one ``SPLIT:N`` names."""
CLASSES = ("tabletop", "room", "outdoor")
"""World classes (scale): a tabletop 0.3–1.5 m, a room 3–8 m, an outdoor ground 10–50 m."""
RESOLUTION = (640, 480)
"""Full-size camera resolution (px); the harness scales it down for quick runs."""
MESHES = ("bunny", "dragon", "lucy", "ring", "bevelled_cube")
"""Bundled meshes (``arlight/data/scenes/meshes``) used as virtual objects."""
TEXTURES = ("planks_brown", "planks_grey", "tiles")
HDR_MAPS = ("light/panoramas/empty_warehouse_01_512x256.hdr",
            "light/panoramas/potsdamer_platz_512x256.hdr",
            "light/panoramas/rooitou_park_512x256.hdr",
            "light/panoramas/st_fagans_interior_512x256.hdr",
            "light/panoramas/studio_small_03_512x256.hdr",
            "light/grace_latlong_256x128.hdr",
            "demo/lebombo_512x256.hdr")
"""Bundled environment maps (paths below ``arlight/data``), drawn for image-based light."""
LIGHT_TYPES = ("area", "sphere", "point", "spot")
"""Local light types (besides the environment and the sun)."""
PLACEMENTS = ("behind", "beside", "front")
"""Where a light stands relative to the camera (see :func:`light_placement`)."""
VIRTUAL_MATERIALS = ("diffuse", "phong", "roughconductor", "mirror", "glass")
VIRTUAL_MATERIAL_P = (0.5, 0.125, 0.125, 0.125, 0.125)
REAL_MATERIALS = ("diffuse", "phong", "roughconductor", "mirror")
REAL_MATERIAL_P = (0.7, 0.12, 0.12, 0.06)
GREY_TARGET = 0.18
"""Display value (linear, before the transfer) of a 50 % grey surface at the objects."""


def data_root() -> Path:
    """The folder of the bundled data (``arlight/data``)."""
    return Path(str(resources.files("arlight") / "data"))


def mesh_path(name: str) -> Path:
    return data_root() / "scenes" / "meshes" / f"{name}.ply"


def texture_path(name: str) -> Path:
    return data_root() / "scenes" / "textures" / f"{name}.png"


# --------------------------------------------------------------------------------------------
# Seeds and splits
# --------------------------------------------------------------------------------------------

def split_of(seed: int) -> str:
    """``"training"`` for seeds below :data:`HELDOUT_BASE`, else ``"heldout"``."""
    if seed < 0:
        raise InputError(f"a world seed is >= 0, got {seed}", field="seed")
    return "training" if seed < HELDOUT_BASE else "heldout"


def split_seeds(split: str, n: int, start: int = 0) -> list[int]:
    """The seeds of the first ``n`` worlds of ``split`` (from its ``start``-th world)."""
    if split not in SPLITS:
        raise InputError(f"unknown split {split!r} (expected one of {', '.join(SPLITS)})",
                         field="worlds")
    if not 1 <= n <= MAX_WORLDS:
        raise InputError(f"the number of worlds must be 1 to {MAX_WORLDS}, got {n}",
                         field="worlds")
    if not 0 <= start < HELDOUT_BASE - n:
        raise InputError(f"the first world must be 0 to {HELDOUT_BASE - n - 1}, got {start}",
                         field="worlds")
    base = 0 if split == "training" else HELDOUT_BASE
    return [base + start + i for i in range(n)]


def parse_worlds(text: str) -> list[int]:
    """Seeds from ``"heldout:24"``, ``"training:8"``, ``"heldout:8+16"`` (8 worlds from the
    16th) or explicit seeds ``"1000003,1000007"``."""
    text = text.strip()
    if ":" in text:
        split, _, count = text.partition(":")
        count, _, start = count.partition("+")
        try:
            n, s = int(count), int(start or 0)
        except ValueError as exc:
            raise InputError(f"expected SPLIT:N or SPLIT:N+START, got {text!r}",
                             field="worlds") from exc
        return split_seeds(split.strip(), n, s)
    try:
        seeds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError as exc:
        raise InputError(f"expected SPLIT:N (e.g. heldout:24) or comma-separated seeds, "
                         f"got {text!r}", field="worlds") from exc
    if not seeds:
        raise InputError("no worlds given", field="worlds")
    for s in seeds:
        split_of(s)
    return seeds


# --------------------------------------------------------------------------------------------
# Numbers as they are written
# --------------------------------------------------------------------------------------------

def _r(x: float) -> float:
    """``x`` rounded to 6 significant digits (what the scene file holds)."""
    return float(f"{float(x):.6g}")


def _v(xs) -> list[float]:
    return [_r(x) for x in xs]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@cache
def mesh_bounds(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(min, max) corners of a bundled mesh in its own units."""
    from arlight.scene.mesh import read_mesh

    v = read_mesh(mesh_path(name)).vertices
    return tuple(map(float, v.min(axis=0))), tuple(map(float, v.max(axis=0)))


@cache
def mean_albedo(path: str) -> tuple[float, float, float]:
    """Mean linear albedo of a texture (sRGB-decoded), as a reconstruction that lost the
    texture would estimate it."""
    from arlight.io.images import mean_linear

    return tuple(_v(mean_linear(path)))


@cache
def mean_radiance(path: str) -> float:
    """Mean luminance (W·sr⁻¹·m⁻²) of an equirect map over the sphere (solid-angle
    weighted), for the exposure estimate."""
    from arlight.io.images import read_linear

    img = read_linear(path)[..., :3]
    h = img.shape[0]
    w = np.sin((np.arange(h) + 0.5) / h * np.pi)[:, None]
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    return float((lum * w).sum() / (w.sum() * img.shape[1]))


# --------------------------------------------------------------------------------------------
# The world
# --------------------------------------------------------------------------------------------

@dataclass
class GeneratedWorld:
    """One generated world.

    Attributes:
        seed: its seed; ``split`` follows from it (:func:`split_of`).
        world_class: one of :data:`CLASSES`.
        world: the world scene dictionary (paths absolute, into the bundled data).
        proxy: the proxy scene dictionary (same camera; coarser real shapes).
        tags: what was drawn, for counting and grouping: ``env`` (``"hdr"``, ``"constant"``,
            ``"none"``), ``hdr`` (file name), ``lights`` (list of ``{type, size, radiance,
            placement}``), ``sun``, ``real_materials``, ``virtual_materials`` (sets of
            types), ``textured``, ``meshes``, ``contact`` (``"touching"`` / ``"floating"``
            per object), ``dof``, ``scale`` (m), ``proxy_edits`` (list of what the proxy
            lost), ``all_diffuse``.
    """

    seed: int
    world_class: str
    world: dict[str, Any]
    proxy: dict[str, Any]
    tags: dict[str, Any] = field(default_factory=dict)

    @property
    def split(self) -> str:
        return split_of(self.seed)

    @property
    def name(self) -> str:
        return f"world-{self.seed}"

    def assets(self) -> list[Path]:
        """Files the two scenes reference (meshes, textures, environment maps)."""
        return sorted({Path(p) for d in (self.world, self.proxy) for p in _paths(d)})

    def scenes(self, width: int | None = None):
        """``(world, proxy)`` as :class:`~arlight.scene.model.ARScene`, optionally at a
        smaller width (same aspect ratio and field of view)."""
        from arlight.scene.load import parse_scene

        out = []
        for kind, data in (("world", self.world), ("proxy", self.proxy)):
            sc = parse_scene(data, data_root(), file=f"{self.name}/{kind}.toml")
            if width is not None and width != sc.camera.width:
                w, h = sc.resolution
                sc = sc.resized(width, max(1, round(width * h / w)))
            out.append(sc)
        return tuple(out)

    def suite_scene(self, width: int | None = None):
        """The world as the evaluation harness runs it
        (:class:`~arlight.evaluate.suite.SuiteScene`, ``quick`` when scaled down): the
        proxy carries the depth a sensor at the camera reads of the real world
        (:func:`arlight.synthetic.sensor_depth`, props the proxy lacks included), the
        RGB-D input of ``probeless``."""
        from dataclasses import replace

        from arlight.evaluate.suite import SuiteScene
        from arlight.synthetic import sensor_depth

        world, proxy = self.scenes(width)
        proxy = replace(proxy, depth=sensor_depth(world))
        return SuiteScene(name=self.name, description=self.describe(),
                          paper_figure=f"generated ({self.split}, {self.world_class})",
                          world=world, proxy=proxy, quick=width not in (None, RESOLUTION[0]))

    def describe(self) -> str:
        """One line: class, scale, environment, lights, materials."""
        t = self.tags
        lights = ", ".join(f"{x['type']} {x['placement']}" for x in t["lights"]) or "none"
        return (f"{self.world_class} {t['scale']:.3g} m; env {t['env']}"
                f"{' + sun' if t['sun'] else ''}; local lights: {lights}; virtual: "
                f"{', '.join(t['meshes'])} ({', '.join(sorted(t['virtual_materials']))})"
                f"{'; depth of field' if t['dof'] else ''}")

    def write(self, folder: str | Path, width: int | None = None,
              frame: dict[str, str] | None = None) -> dict[str, Path]:
        """Write ``world.toml``, ``proxy.toml`` and the assets they use (copied into
        ``assets/``, so the folder stands alone) into ``folder``; returns the paths.

        ``width``: the camera's width in pixels (default :data:`RESOLUTION`; the height keeps
        the aspect ratio). ``frame``: the proxy's ``[frame]`` table (e.g. ``{"image":
        "frame.exr", "depth": "depth.exr"}``), so that it is a method's input as written.
        """
        from arlight.scene.save import to_toml

        folder = Path(folder)
        (folder / "assets").mkdir(parents=True, exist_ok=True)
        local = {}
        for p in self.assets():
            dst = folder / "assets" / p.name
            shutil.copyfile(p, dst)
            local[str(p)] = f"assets/{p.name}"
        out = {}
        for kind, data in (("world", self.world), ("proxy", self.proxy)):
            data = _relocated(data, local)
            if width is not None:
                w, h = data["camera"]["resolution"]
                data["camera"]["resolution"] = [width, max(1, round(width * h / w))]
            if kind == "proxy" and frame:
                data = {**{k: v for k, v in data.items() if k not in ("materials", "shapes",
                                                                      "lights")},
                        "frame": dict(frame), "materials": data["materials"],
                        "shapes": data["shapes"], "lights": data["lights"]}
            text = f"# {self.name} ({self.split}, generator v{GENERATOR_VERSION}): " \
                   f"{self.describe()}\n" + to_toml(data)
            path = folder / f"{kind}.toml"
            path.write_text(text, encoding="utf-8")
            out[kind] = path
        return out


_PATH_KEYS = ("file", "texture")


def _paths(data: Any):
    if isinstance(data, dict):
        for k, v in data.items():
            if k in _PATH_KEYS and isinstance(v, str):
                yield v
            else:
                yield from _paths(v)
    elif isinstance(data, list):
        for v in data:
            yield from _paths(v)


def _relocated(data: Any, local: dict[str, str]) -> Any:
    if isinstance(data, dict):
        return {k: (local.get(v, v) if k in _PATH_KEYS and isinstance(v, str)
                    else _relocated(v, local)) for k, v in data.items()}
    if isinstance(data, list):
        return [_relocated(v, local) for v in data]
    return data


class _Draw:
    """The world being drawn: random numbers, materials, shapes, lights."""

    def __init__(self, seed: int):
        self.rng = np.random.Generator(np.random.PCG64(seed))
        self.materials: dict[str, dict[str, Any]] = {}
        self.shapes: list[dict[str, Any]] = []
        self.lights: list[dict[str, Any]] = []
        self.tags: dict[str, Any] = {"lights": [], "real_materials": set(),
                                     "virtual_materials": set(), "textured": False,
                                     "meshes": [], "contact": [], "proxy_edits": []}
        self.proxy_drop: set[str] = set()
        self.proxy_offset: dict[str, list[float]] = {}
        self.bevelled: set[str] = set()

    def u(self, a: float, b: float) -> float:
        return float(self.rng.uniform(a, b))

    def logu(self, a: float, b: float) -> float:
        return float(math.exp(self.rng.uniform(math.log(a), math.log(b))))

    def pick(self, options, p=None):
        return options[int(self.rng.choice(len(options), p=p))]

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def colour(self, lo: float = 0.05, hi: float = 0.85) -> list[float]:
        return _v(self.rng.uniform(lo, hi, 3))

    # ---------------------------------------------------------------------------- materials
    def material(self, name: str, role: str, textured_ok: bool = False) -> str:
        if role == "virtual":
            kind = self.pick(VIRTUAL_MATERIALS, VIRTUAL_MATERIAL_P)
        else:
            kind = self.pick(REAL_MATERIALS, REAL_MATERIAL_P)
        m: dict[str, Any] = {"type": kind}
        if kind == "diffuse":
            if textured_ok and self.chance(0.5):
                m["texture"] = str(texture_path(self.pick(TEXTURES)))
                self.tags["textured"] = True
            else:
                m["albedo"] = self.colour()
        elif kind == "phong":
            kd = self.rng.uniform(0.05, 0.7, 3)
            ks = self.u(0.05, 0.25)
            m.update(kd=_v(kd), ks=_r(ks), exponent=_r(self.logu(5, 200)))
        elif kind == "roughconductor":
            m.update(alpha=_r(self.logu(0.05, 0.5)), reflectance=self.colour(0.3, 0.95))
        elif kind == "mirror":
            m["reflectance"] = self.colour(0.6, 0.95)
        else:  # glass
            m["ior"] = _r(self.u(1.3, 1.7))
        self.tags[f"{role}_materials"].add(kind)
        self.materials[name] = m
        return name

    # ---------------------------------------------------------------------------- shapes
    def shape(self, name: str, role: str, kind: str, material: str, **params) -> None:
        self.shapes.append({"name": name, "role": role, "type": kind, **params,
                            "material": material})

    def real_box(self, name: str, size, centre, yaw: float, textured_ok: bool = False,
                 small: bool = False) -> None:
        """A real box; the world has it bevelled (the proxy a sharp box) with chance 1/2,
        and a small one is missing from the proxy with chance 1/2."""
        bevelled = self.chance(0.5)
        mat = self.material(name, "real", textured_ok and not bevelled)  # the mesh: no UVs
        size = _v(size)
        tf = {"rotate": [0.0, 1.0, 0.0, _r(yaw)], "translate": _v(centre)}
        if bevelled:
            # bevelled_cube.ply is the unit cube [-0.5, 0.5]^3 with bevelled edges
            self.shape(name, "real", "mesh", mat, file=str(mesh_path("bevelled_cube")),
                       transform={"scale": size, **tf})
            self.bevelled.add(name)
        else:
            self.shape(name, "real", "box", mat, size=size, transform=tf)
        if small and self.chance(0.5):
            self.proxy_drop.add(name)

    def real_sphere(self, name: str, radius: float, centre, small: bool = False) -> None:
        mat = self.material(name, "real")
        self.shape(name, "real", "sphere", mat, radius=_r(radius),
                   transform={"translate": _v(centre)})
        if small and self.chance(0.5):
            self.proxy_drop.add(name)

    def rect(self, name: str, size, normal, centre, material: str) -> None:
        self.shape(name, "real", "rectangle", material, size=_v(size), normal=_v(normal),
                   transform={"translate": _v(centre)})


# --------------------------------------------------------------------------------------------
# Placement helpers
# --------------------------------------------------------------------------------------------

def light_placement(position, camera_origin, target) -> str:
    """Where a light at ``position`` stands for a camera at ``camera_origin`` looking at
    ``target`` (horizontal angle from the camera's view direction at the target): within 60°
    of the view direction beyond the target ``"front"`` (lighting the camera-facing side from
    behind the scene), within 60° of the opposite ``"behind"`` (on the camera's side), else
    ``"beside"``."""
    fwd = np.asarray(target, float) - np.asarray(camera_origin, float)
    d = np.asarray(position, float) - np.asarray(target, float)
    fwd[1] = d[1] = 0.0
    if np.linalg.norm(d) < 1e-9:
        return "beside"  # straight above the target
    c = float(np.dot(_unit(fwd), _unit(d)))
    return "front" if c > 0.5 else "behind" if c < -0.5 else "beside"


def _direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])


# --------------------------------------------------------------------------------------------
# Generation
# --------------------------------------------------------------------------------------------

def generate(seed: int) -> GeneratedWorld:
    """The world of ``seed`` (see the module docstring for the distribution)."""
    split_of(seed)
    d = _Draw(seed)
    world_class = d.pick(CLASSES)
    scale = {"tabletop": lambda: d.logu(0.3, 1.5), "room": lambda: d.u(3.0, 8.0),
             "outdoor": lambda: d.logu(10.0, 50.0)}[world_class]()
    d.tags["scale"] = _r(scale)
    room = _real_world(d, world_class, scale)
    target, obj_size = _virtual_objects(d, world_class, scale, room)
    cam = _camera(d, world_class, scale, target, obj_size, room)
    env_irr = _environment(d, world_class, room)
    local_irr = _local_lights(d, world_class, scale, target, cam["look_at"]["origin"], room,
                              env_irr)
    cam["exposure"] = auto_exposure(env_irr + local_irr)
    world = {"format": "arlight-scene/1",
             "description": f"generated world {seed} ({world_class})",
             "camera": cam, "materials": d.materials, "shapes": d.shapes,
             "lights": d.lights}
    proxy = _proxy(d, world, scale)
    d.tags["all_diffuse"] = (d.tags["real_materials"] | d.tags["virtual_materials"]) \
        <= {"diffuse"}
    return GeneratedWorld(seed=seed, world_class=world_class, world=world, proxy=proxy,
                          tags=d.tags)


def auto_exposure(irradiance: float) -> float:
    """Exposure (EV) that shows a 50 % grey diffuse surface under ``irradiance`` (W/m²) at
    :data:`GREY_TARGET`: radiance ``0.5 E / π``, ``exposure = log2(0.18 / that)``."""
    radiance = 0.5 * max(irradiance, 1e-9) / math.pi
    return _r(round(min(max(math.log2(GREY_TARGET / radiance), -40.0), 40.0), 2))


def _real_world(d: _Draw, world_class: str, scale: float) -> dict[str, Any] | None:
    """The real shapes; returns the room's box (``{"size": [w, h, l]}``) for rooms."""
    ground = d.material("ground", "real", textured_ok=True) if d.chance(0.85) else None
    if ground is None:  # a plain diffuse ground
        d.materials["ground"] = {"type": "diffuse", "albedo": d.colour(0.1, 0.7)}
        d.tags["real_materials"].add("diffuse")
        ground = "ground"
    if d.materials["ground"]["type"] == "mirror":  # a mirror floor is too rare to matter
        d.materials["ground"] = {"type": "diffuse", "albedo": d.colour(0.1, 0.7)}
    room = None
    if world_class == "room":
        w, length, h = scale, scale * d.u(0.8, 1.3), d.u(2.4, 3.5)
        room = {"size": [w, h, length]}
        d.rect("floor", [w, length], [0, 1, 0], [0, 0, 0], ground)
        walls = d.material("walls", "real", textured_ok=False)
        if d.materials[walls]["type"] == "mirror":
            d.materials[walls] = {"type": "diffuse", "albedo": d.colour(0.3, 0.85)}
        d.rect("ceiling", [w, length], [0, -1, 0], [0, h, 0], walls)
        open_wall = d.pick(("none", "none", "+x", "-x", "+z", "-z"))
        for side, normal, centre, size in (
                ("+x", [-1, 0, 0], [w / 2, h / 2, 0], [length, h]),
                ("-x", [1, 0, 0], [-w / 2, h / 2, 0], [length, h]),
                ("+z", [0, 0, -1], [0, h / 2, length / 2], [w, h]),
                ("-z", [0, 0, 1], [0, h / 2, -length / 2], [w, h])):
            if side != open_wall:
                d.rect(f"wall{side}", size, normal, centre, walls)
        room["open"] = open_wall
        d.tags["room_open"] = open_wall
        n_props, prop = d.pick((1, 2, 3)), (0.3, 1.2)
    else:
        extent = scale * (2.0 if world_class == "tabletop" else 1.0)
        d.rect("ground", [extent, extent], [0, 1, 0], [0, 0, 0], ground)
        if world_class == "tabletop" and d.chance(0.4):  # a wall behind the table
            wall = d.material("backwall", "real")
            d.rect("backwall", [extent, extent / 2], [0, 0, 1],
                   [0, extent / 4, -scale * d.u(0.35, 0.6)], wall)
        n_props = d.pick((0, 1, 2, 3))
        prop = (0.08, 0.3) if world_class == "tabletop" else (0.03, 0.12)
    for i in range(n_props):
        # props on a ring around the virtual objects' spot (the origin), clear of them
        s = scale * d.u(*prop) if world_class != "room" else d.u(*prop)
        r = 0.3 * scale + 0.75 * s + scale * d.u(0.0, 0.25)
        if room is not None:
            r = min(r, 0.45 * min(room["size"][0], room["size"][2]) - 0.75 * s)
        a = d.u(0, 2 * math.pi)
        c = np.array([r * math.sin(a), 0.0, r * math.cos(a)])
        small = s < 0.12 * scale
        if d.chance(0.65):
            size = [s * d.u(0.6, 1.4), s * d.u(0.3, 1.2), s * d.u(0.6, 1.4)]
            d.real_box(f"prop{i}", size, c + [0, size[1] / 2, 0], d.u(0, 90), True, small)
        else:
            d.real_sphere(f"prop{i}", s / 2, c + [0, s / 2, 0], small)
    return room


def _virtual_objects(d: _Draw, world_class: str, scale: float,
                     room: dict | None) -> tuple[np.ndarray, float]:
    """1–2 virtual objects near the origin; returns the point the camera aims at and the
    objects' overall size (m)."""
    n = 1 if d.chance(0.6) else 2
    rel = {"tabletop": (0.1, 0.25), "room": (0.08, 0.25), "outdoor": (0.03, 0.12)}[world_class]
    centres, top = [], 0.0
    for i in range(n):
        size = scale * d.u(*rel)
        if world_class == "room":
            size = min(size, 0.6 * room["size"][1])
        kind = d.pick((*MESHES, "sphere", "box"), p=(0.2, 0.15, 0.15, 0.1, 0.1, 0.15, 0.15))
        mat = d.material(f"virtual{i}", "virtual")
        offset = np.array([d.u(-0.1, 0.1), 0.0, d.u(-0.1, 0.1)]) * scale if i else \
            np.zeros(3)
        touching = d.chance(0.65)
        lift = 0.001 * scale if touching else size * d.u(0.1, 0.6)
        d.tags["contact"].append("touching" if touching else "floating")
        yaw = d.u(0, 360)
        if kind in MESHES:
            lo, hi = mesh_bounds(kind)
            k = size / max(hi[1] - lo[1], hi[0] - lo[0], hi[2] - lo[2])
            mid = np.array([(lo[0] + hi[0]) / 2, 0.0, (lo[2] + hi[2]) / 2]) * k
            pos = offset - mid + [0.0, lift - lo[1] * k, 0.0]
            d.shape(f"virtual{i}", "virtual", "mesh", mat, file=str(mesh_path(kind)),
                    transform={"scale": _r(k), "rotate": [0.0, 1.0, 0.0, _r(yaw)],
                               "translate": _v(pos)})
            height = (hi[1] - lo[1]) * k
        elif kind == "sphere":
            d.shape(f"virtual{i}", "virtual", "sphere", mat, radius=_r(size / 2),
                    transform={"translate": _v(offset + [0, lift + size / 2, 0])})
            height = size
        else:
            dims = [size * d.u(0.5, 1.0), size * d.u(0.5, 1.0), size * d.u(0.5, 1.0)]
            d.shape(f"virtual{i}", "virtual", "box", mat, size=_v(dims),
                    transform={"rotate": [0.0, 1.0, 0.0, _r(yaw)],
                               "translate": _v(offset + [0, lift + dims[1] / 2, 0])})
            height = dims[1]
        d.tags["meshes"].append(kind)
        centres.append(offset)
        top = max(top, lift + height)
    target = np.mean(centres, axis=0) + [0.0, top * 0.45, 0.0]
    return target, max(top, scale * rel[0])


def _camera(d: _Draw, world_class: str, scale: float, target: np.ndarray, size: float,
            room: dict | None) -> dict[str, Any]:
    fov = d.u(35.0, 70.0)
    fill = d.u(0.25, 0.6)  # fraction of the image height the objects take
    dist = size / (2 * math.tan(math.radians(fov) / 2) * fill)
    elev = d.u(8.0, 45.0) if world_class != "outdoor" else d.u(3.0, 30.0)
    azim = d.u(-180.0, 180.0)
    if room is not None:  # stay inside the room, below the ceiling
        w, h, length = room["size"]
        dist = min(dist, 0.35 * min(w, length))
        elev = min(elev, math.degrees(math.asin(min(1.0, (0.9 * h - target[1]) / dist))))
    origin = target + dist * _direction(azim, elev)
    cam: dict[str, Any] = {"resolution": list(RESOLUTION), "fov_y_deg": _r(fov),
                           "look_at": {"origin": _v(origin), "target": _v(target),
                                       "up": [0.0, 1.0, 0.0]},
                           "transfer": "srgb"}
    d.tags["dof"] = d.chance(0.3)
    if d.tags["dof"]:
        # a circle of confusion of a few pixels a third of the distance off focus
        cam["aperture_radius"] = _r(dist * d.u(0.004, 0.02))
        cam["focus_distance"] = _r(dist * d.u(0.9, 1.1))
    return cam


def _environment(d: _Draw, world_class: str, room: dict | None) -> float:
    """The environment light; returns its estimated irradiance at the objects (W/m²)."""
    closed = room is not None and room["open"] == "none"
    p_none = 0.5 if closed else 0.0
    kind = d.pick(("hdr", "constant", "none"), p=((1 - p_none) * 0.7, (1 - p_none) * 0.3,
                                                   p_none))
    d.tags["env"] = kind
    d.tags["hdr"] = ""
    if kind == "none":
        return 0.0
    if kind == "hdr":
        rel = d.pick(HDR_MAPS)
        path = data_root() / rel
        scale = d.logu(0.25, 4.0)
        d.lights.append({"type": "envmap", "file": str(path), "scale": _r(scale),
                         "rotation_deg": _r(d.u(0.0, 360.0))})
        d.tags["hdr"] = path.name
        radiance = mean_radiance(str(path)) * scale
    else:
        radiance = d.logu(0.05, 2.0)
        tint = np.array([1.0, 1.0, 1.0]) + d.rng.uniform(-0.15, 0.15, 3)
        d.lights.append({"type": "constant", "radiance": _v(radiance * tint)})
    blocked = 0.9 if room is not None else 0.0  # a room lets little of the sky in
    return math.pi * radiance * (1.0 - blocked)


def _local_lights(d: _Draw, world_class: str, scale: float, target: np.ndarray,
                  cam_origin, room: dict | None, env_irr: float) -> float:
    """0–3 local lights (at least one without an environment or in a closed room) and,
    outdoors, a sun; returns their estimated irradiance at the objects (W/m²). Each light's
    share is drawn log-uniform over three orders of magnitude relative to a base irradiance
    (the environment's, or 1 W/m² without one)."""
    base = env_irr if env_irr > 0 else 1.0
    total = 0.0
    d.tags["sun"] = world_class == "outdoor" and d.chance(0.5)
    if d.tags["sun"]:
        e_sun = base * d.logu(0.3, 30.0)
        direction = -_direction(d.u(-180, 180), d.u(12.0, 70.0))
        d.lights.append({"type": "directional", "direction": _v(direction),
                         "irradiance": _v(e_sun * np.array([1.0, 0.95, 0.85]))})
        total += e_sun * max(0.0, -direction[1])
    closed = room is not None and room["open"] == "none"
    lo = 1 if d.tags["env"] == "none" or closed else 0  # light must reach the objects
    n = d.pick(tuple(range(lo, 4)))
    fwd = np.asarray(target) - np.asarray(cam_origin)
    cam_az = math.degrees(math.atan2(fwd[0], fwd[2]))
    for _ in range(n):
        kind = d.pick(LIGHT_TYPES, p=(0.4, 0.25, 0.2, 0.15))
        placement = d.pick(PLACEMENTS)
        centre_az = {"front": cam_az, "behind": cam_az + 180.0,
                     "beside": cam_az + d.pick((-90.0, 90.0))}[placement]
        az = centre_az + d.u(-35.0, 35.0)
        elev = d.u(20.0, 70.0)
        r = scale * d.u(0.4, 1.0) if world_class != "outdoor" else d.u(2.0, 0.4 * scale)
        if placement == "behind":  # behind the camera, not between it and the objects
            r = max(r, 1.1 * float(np.linalg.norm(fwd)))
        pos = np.asarray(target) + r * _direction(az, elev)
        if room is not None:  # inside the room, below the ceiling
            w, h, length = room["size"]
            pos = np.clip(pos, [-0.45 * w, 0.3, -0.45 * length], [0.45 * w, 0.95 * h,
                                                                  0.45 * length])
        to_t = np.asarray(target) - pos
        dist = float(np.linalg.norm(to_t))
        e_light = base * d.logu(0.1, 100.0)
        colour = np.array([1.0, 1.0, 1.0]) + d.rng.uniform(-0.2, 0.2, 3)
        info = {"type": kind, "placement": light_placement(pos, cam_origin, target),
                "size": 0.0, "radiance": 0.0}
        if kind in ("area", "sphere"):
            size = d.logu(0.01, min(2.0, 0.6 * dist))
            info["size"] = _r(size)
            if kind == "area":
                other = size * d.u(0.5, 1.0)  # facing the target: E ≈ L·A/dist²
                radiance = e_light * dist**2 / (size * other)
                d.lights.append({"type": "area", "size": _v([size, other]),
                                 "normal": _v(_unit(to_t)), "transform": {"translate":
                                                                          _v(pos)},
                                 "radiance": _v(radiance * colour)})
            else:
                radius = size / 2
                intensity = e_light * dist**2
                radiance = intensity / (math.pi * radius**2)
                d.lights.append({"type": "sphere", "position": _v(pos), "radius": _r(radius),
                                 "intensity": _v(intensity * colour)})
            info["radiance"] = _r(radiance)
        elif kind == "point":
            d.lights.append({"type": "point", "position": _v(pos),
                             "intensity": _v(e_light * dist**2 * colour)})
        else:
            cutoff = d.u(20.0, 60.0)
            d.lights.append({"type": "spot", "position": _v(pos), "target": _v(target),
                             "intensity": _v(e_light * dist**2 * colour),
                             "cutoff_deg": _r(cutoff),
                             "beam_width_deg": _r(cutoff * d.u(0.5, 0.9))})
        d.tags["lights"].append(info)
        total += e_light
    return total


def _proxy(d: _Draw, world: dict[str, Any], scale: float) -> dict[str, Any]:
    """The proxy: textures lost to their mean albedo, bevelled boxes sharp, small objects
    missing, one real surface offset by 0.5–3 % of the world's size."""
    proxy = copy.deepcopy(world)
    proxy["description"] = world["description"].replace("generated world",
                                                        "proxy of generated world")
    edits = d.tags["proxy_edits"]
    for name, m in proxy["materials"].items():
        if "texture" in m:
            m.pop("texture")
            m["albedo"] = list(mean_albedo(world["materials"][name]["texture"]))
            edits.append(f"{name}: texture lost (mean albedo)")
    shapes = []
    for s in proxy["shapes"]:
        if s["name"] in d.proxy_drop:
            edits.append(f"{s['name']}: missing")
            continue
        if s["name"] in d.bevelled:
            tf = dict(s["transform"])
            size = tf.pop("scale")
            s = {"name": s["name"], "role": "real", "type": "box", "size": size,
                 "transform": tf, "material": s["material"]}
            edits.append(f"{s['name']}: bevels lost")
        shapes.append(s)
    real = [s for s in shapes if s["role"] == "real" and s["type"] != "rectangle"
            or s["name"] in ("backwall", "wall+x", "wall-x", "wall+z", "wall-z")]
    if real:
        s = real[int(d.rng.integers(len(real)))]
        shift = _direction(d.u(-180, 180), 0.0) * scale * d.u(0.005, 0.03)
        tf = dict(s.get("transform", {}))
        tf["translate"] = _v(np.asarray(tf.get("translate", [0, 0, 0])) + shift)
        s["transform"] = tf
        edits.append(f"{s['name']}: offset {np.linalg.norm(shift) * 1000:.0f} mm")
    proxy["shapes"] = shapes
    return proxy


__all__ = ["CLASSES", "GENERATOR_VERSION", "GeneratedWorld", "HELDOUT_BASE", "SPLITS",
           "auto_exposure", "generate", "light_placement", "parse_worlds", "split_of",
           "split_seeds"]
