"""Light reduction: the world's lights as the few lights a real-time method takes.

Volume and many-light methods (DLPV, DIR, DVCT) render one reflective shadow map per light,
so they take a handful of point, spot and directional lights, the "reconstructed real light
sources" of Franke 2013 §4.3 (16 extracted from the fisheye image in the thesis, Fig. 2.15).
:func:`reduce_lights` turns every light of a :class:`~arlight.scene.model.World` into:

* ``point`` / ``spot`` / ``directional`` lights: kept as they are;
* ``area`` (one-sided emitting rectangle of radiance ``L``, area ``A``, normal ``n``): a
  ``g × g`` grid of **cosine points** at the patch centres, each with radiant intensity
  ``I(ω) = L · A/g² · <n, ω>+`` (W/sr), the far field of a Lambertian patch;
* ``envmap`` / ``sh`` / ``constant``: the light estimate of the map
  (:meth:`arlight.light.estimate.LightEstimate.from_envmap`, the same one ``arlight light
  estimate`` makes): each connected region above ``threshold_factor`` × the mean luminance
  is one directional light with all of its energy (a sun is one light, not fragments), at
  most ``env_lights`` of them; the remainder is projected onto 9 SH coefficients per channel
  (order 2) and kept as **ambient** light (:attr:`LightSet.ambient_sh`, radiance). A
  constant environment is all ambient.

Energy is kept: the cosine points of an area light emit its total power ``π L A``; the
directional lights plus the ambient SH integrate to the map's irradiance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from arlight.errors import InputError
from arlight.scene.model import World
from arlight.scene.schema import Field
from arlight.sphere.sh import LUMINANCE, rotate

KINDS = ("point", "cosine", "spot", "directional")

OPTIONS: dict[str, Field] = {
    "env_lights": Field("int", 4, "directional lights extracted from an environment map's "
                        "highlight regions (at most); the rest is SH ambient", "", min=0, max=256),
    "area_grid": Field("int", 1, "cosine point lights per side of an area light", "", min=1,
                       max=16),
}
"""The light-reduction settings every method built on :func:`reduce_lights` exposes."""


@dataclass(frozen=True)
class ReducedLight:
    """One light of a reduced set.

    Attributes:
        kind: ``point`` (isotropic), ``cosine`` (Lambertian patch: ``I(ω) = I0 <axis, ω>+``),
            ``spot`` (Mitsuba's spot: full intensity inside ``beam``, falling linearly in
            angle to zero at ``cutoff``) or ``directional``.
        position: world position (m); unused for directional lights.
        axis: unit vector: emission normal (cosine), spot axis (spot), direction of travel
            (directional); unused for point lights.
        intensity: RGB radiant intensity ``I0`` (W/sr) along the axis; for directional
            lights the irradiance (W/m²) at normal incidence.
        cos_cutoff, cos_beam: spot cone (cosines of the half angles).
        source: name of the world light it came from.
        spread: angular radius (rad) of the region of sky a directional light extracted
            from an environment stands for (its highlight region's ``spread``,
            :func:`arlight.light.extract.find_highlights`); 0: a true direction.
        extent: ``(2, 3)`` half-edge vectors (m) of the patch a ``cosine`` point stands for
            (its cell of the area light's ``g × g`` grid); zeros: a true point.
            ``spread`` and ``extent`` are the light's size for soft shadows
            (:func:`arlight.realtime.shading.direct_change`); the light's emission is the
            point's (or direction's) either way.
    """

    kind: str
    position: np.ndarray
    axis: np.ndarray
    intensity: np.ndarray
    cos_cutoff: float = -1.0
    cos_beam: float = -1.0
    source: str = ""
    spread: float = 0.0
    extent: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown reduced light kind {self.kind!r}")

    @property
    def power(self) -> float:
        """Emitted power (W, luminance-weighted mean of RGB); 0 for directional lights."""
        y = float(np.asarray(self.intensity) @ LUMINANCE)
        if self.kind == "point":
            return 4.0 * math.pi * y
        if self.kind == "cosine":
            return math.pi * y
        if self.kind == "spot":
            return 2.0 * math.pi * (1.0 - 0.5 * (self.cos_cutoff + self.cos_beam)) * y
        return 0.0


@dataclass
class LightSet:
    """Reduced lights plus the SH ambient remainder ``(9, 3)`` (radiance coefficients in
    the basis of :mod:`arlight.sphere.sh`; zero when the world has no environment)."""

    lights: list[ReducedLight]
    ambient_sh: np.ndarray = field(default_factory=lambda: np.zeros((9, 3)))

    def scaled(self, k: float) -> LightSet:
        """Every light and the ambient term multiplied by ``k`` (linearity tests)."""
        return LightSet([replace(x, intensity=x.intensity * k) for x in self.lights],
                        self.ambient_sh * k)


def _rot_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _area(name: str, p: dict, grid: int) -> list[ReducedLight]:
    m = np.asarray(p["to_world"], np.float64)
    a = m[:3, 0] * p["size"][0] / 2.0
    b = m[:3, 1] * p["size"][1] / 2.0
    nrm = np.cross(a, b)
    area = 4.0 * float(np.linalg.norm(nrm))
    nrm = nrm / max(np.linalg.norm(nrm), 1e-300)
    radiance = np.broadcast_to(np.asarray(p["radiance"], np.float64), (3,))
    centre = m[:3, 3]
    out = []
    for i in range(grid):
        for j in range(grid):
            u = -1.0 + (2 * i + 1) / grid
            v = -1.0 + (2 * j + 1) / grid
            out.append(ReducedLight("cosine", centre + u * a + v * b, nrm,
                                    radiance * area / grid**2, source=name,
                                    extent=np.stack([a / grid, b / grid])))
    return out


def _environment(name: str, image: np.ndarray, rotation_deg: float, env_lights: int,
                 threshold_factor: float) -> tuple[list[ReducedLight], np.ndarray]:
    from arlight.light.estimate import LightEstimate
    from arlight.light.extract import auto_threshold

    img = np.asarray(image, np.float64)[..., :3]
    rot = _rot_y(rotation_deg)
    est = LightEstimate.from_envmap(img, n_lights=env_lights, sh_order=2, keep_map=False,
                                    threshold=auto_threshold(img, threshold_factor))
    spreads = [est.main_spread] + [x.spread for x in est.lights]  # explicit_lights' order
    lights = [ReducedLight("directional", np.zeros(3), -(rot @ x.direction),
                           np.asarray(x.irradiance, np.float64).copy(), source=name,
                           spread=float(r))
              for x, r in zip(est.explicit_lights(), spreads, strict=True)
              if float(np.max(x.irradiance)) > 0.0]
    sh = est.sh
    if abs(rotation_deg) > 0.0:
        sh = rotate(sh, rot)
    return lights, np.asarray(sh, np.float64).reshape(9, 3)


REDUCIBLE_LIGHTS = frozenset({"point", "spot", "directional", "area", "constant", "envmap",
                              "sh"})
"""Light types :func:`reduce_lights` handles (not ``sphere``): the ``lights`` capability of
every method built on it, so a world with a sphere light is skipped by the harness instead of
failing in ``prepare``."""


def reduce_lights(world: World, env_lights: int = 4, area_grid: int = 1,
                  threshold_factor: float = 4.0) -> LightSet:
    """The reduced lights of ``world`` (see the module docstring).

    Args:
        env_lights: directional lights extracted from each environment's highlights.
        area_grid: cosine points per side of each area light (``area_grid²`` in all).
        threshold_factor: environment highlight threshold, × the mean luminance.

    Raises:
        InputError (field ``lights``): the world has no light, or none that emits.
    """
    lights: list[ReducedLight] = []
    ambient = np.zeros((9, 3))
    for i, lt in enumerate(world.lights):
        name = lt.name or f"light{i}"
        p = lt.params
        if lt.type == "point":
            lights.append(ReducedLight("point", np.asarray(p["position"], np.float64),
                                       np.zeros(3), np.broadcast_to(
                                           np.asarray(p["intensity"], np.float64), (3,)).copy(),
                                       source=name))
        elif lt.type == "spot":
            pos = np.asarray(p["position"], np.float64)
            axis = np.asarray(p["target"], np.float64) - pos
            axis /= max(np.linalg.norm(axis), 1e-300)
            lights.append(ReducedLight(
                "spot", pos, axis,
                np.broadcast_to(np.asarray(p["intensity"], np.float64), (3,)).copy(),
                cos_cutoff=math.cos(math.radians(p["cutoff_deg"])),
                cos_beam=math.cos(math.radians(min(p["beam_width_deg"], p["cutoff_deg"]))),
                source=name))
        elif lt.type == "directional":
            d = np.asarray(p["direction"], np.float64)
            lights.append(ReducedLight("directional", np.zeros(3), d / np.linalg.norm(d),
                                       np.broadcast_to(np.asarray(p["irradiance"], np.float64),
                                                       (3,)).copy(), source=name))
        elif lt.type == "area":
            lights.extend(_area(name, p, area_grid))
        elif lt.type == "constant":
            rad = np.broadcast_to(np.asarray(p["radiance"], np.float64), (3,))
            ambient[0] += rad * math.sqrt(4.0 * math.pi)  # L · ∫ Y00 dω
        elif lt.type in ("envmap", "sh"):
            img = np.asarray(lt.radiance_map, np.float64) * float(p.get("scale", 1.0))
            env, sh = _environment(name, img, float(p.get("rotation_deg", 0.0)), env_lights,
                                   threshold_factor)
            lights.extend(env)
            ambient += sh
        else:  # pragma: no cover - the schema knows every type
            raise InputError(f"light type {lt.type!r} cannot be reduced", field="lights")
    lights = [x for x in lights if float(np.max(x.intensity)) > 0.0]
    if not lights and not np.any(ambient):
        raise InputError("the scene has no light that can be reduced to point, spot or "
                         "directional lights (add a [[lights]] table)", field="lights")
    return LightSet(lights, ambient)


__all__ = ["KINDS", "LightSet", "ReducedLight", "reduce_lights"]
