"""The virtual objects' occlusion of the SH ambient remainder, for the methods that shade
real pixels additively (``dlpv``, ``dir``; issue #33).

After the light reduction (:mod:`arlight.realtime.light_reduction`) an environment-lit
world keeps part of its light as the SH ambient remainder ``L_a(ω)`` (radiance, order 2).
Those methods add only the *change* of light to a real pixel,
``C = B + ρ/π ΔE``; the change of the ambient part that an inserted object makes at a real
point ``x`` with normal ``n`` is the irradiance it blocks,

    ΔE_a(x) = − ∫_Ω L_a(ω) O_x(ω) <n, ω>+ dω,                                        (1)

``O_x(ω) = 1`` where the ray from ``x`` along ``ω`` hits a virtual object. With ``L_a``,
``O_x`` and the clamped cosine in SH this is Franke's AR object occlusion field lookup
(thesis §5.2, Eqs. 5.1–5.9: the triple product ``Σ_ijk C_ijk L_i O_j T_k``), which
:meth:`arlight.realtime.oof.OcclusionField.occluded_irradiance` evaluates (the field ``ibl``
and ``prt`` build, same options :data:`~arlight.realtime.oof.OOF_OPTIONS`). It is clipped to
``[0, E_a(n)]`` (no more light can be blocked than arrives). ``O_x`` counts directions that
the real scene blocks too (the field holds the virtual shapes alone): a point that the
proxy already shadows from those directions loses too much — Franke's approximation as well.

On a virtual object the same remainder arrives through its own occlusion. ``dlpv`` and
``dir`` shaded it unoccluded (``E_a(n)``); here it is weighted by the ray-traced ambient
occlusion of the virtual shapes (Franke Eq. 2.29, :func:`arlight.realtime.ibl_shading.
ambient_occlusion`, as ``ibl`` does):

    E_a,virtual(x) ≈ A(x) E_a(n),   A(x) = 1/π ∫_Ω (1 − O_x(ω)) <n, ω>+ dω,             (2)

exact for a constant ``L_a``, an approximation (the usual one) for a directional one.

Units: metres, irradiance W/m².
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneView
from arlight.jit import opaques
from arlight.realtime.ibl_shading import ambient_occlusion
from arlight.realtime.light_reduction import LightSet
from arlight.realtime.oof import (
    OOF_OPTIONS,
    Occluder,
    OcclusionField,
    field_from_options,
    make_occluder,
    move_occluder,
    pose_field,
    virtual_moved,
)
from arlight.realtime.shading import ambient_irradiance_dr, on_active, virtual_bounds
from arlight.scene.model import World
from arlight.scene.schema import Field
from arlight.sphere.sh import Y00

AMBIENT_OPTIONS: dict[str, Field] = {
    **OOF_OPTIONS,
    "ambient_bounce": Field("bool", True, "the virtual objects' own reflection of the "
                            "ambient remainder fills their shadow on real surfaces (Eq. 3 "
                            "of arlight.realtime.ambient: the blocked radiance replaced by "
                            "ρ_v × the remainder's mean); off: the blocked light is lost"),
    "ao_rays": Field("int", 0, "ambient-occlusion rays per virtual pixel against the virtual "
                     "shapes, weighting the SH ambient remainder on the objects (Eq. 2 "
                     "with Eq. 3's fill; 0: unoccluded — on 12 training worlds 16 rays "
                     "changed dlpv by −0.04…+0.03 dB and dir by −0.10…0 dB)", "", min=0,
                     max=1024),
}
"""Options of the ambient occlusion: the occlusion field's (``oof``: the objects' shadow of
the ambient remainder on real surfaces, Eq. 1) and ``ao_rays`` (their self-occlusion,
Eq. 2)."""

ENV_TYPES = ("envmap", "sh", "constant")
"""World light types whose reduction leaves an SH ambient remainder."""


@dataclass
class AmbientOcclusion:
    """What the ambient occlusion of a prepared world keeps.

    Attributes:
        occluder: the virtual shapes alone (:func:`~arlight.realtime.oof.make_occluder`;
            None: no virtual shape or no ambient remainder).
        field: their occlusion field (None: ``oof`` off, or no occluder).
        distance: the AO rays' length (m): the diagonal of the virtual objects' box.
    """

    occluder: Occluder | None
    field: OcclusionField | None
    distance: float
    albedo: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @staticmethod
    def none() -> AmbientOcclusion:
        """No occlusion (the remainder is shaded unoccluded)."""
        return AmbientOcclusion(None, None, math.inf)


def ambient_drag_options(options, factor: int) -> dict[str, int]:
    """The occlusion field's share of a studio drag frame at 1/``factor`` of the size
    (issue #32, a method's ``drag_options``): rays per shell sample ÷ ``factor²`` (at least
    64) and shells ÷ ``factor`` (at least 8) — a world with several virtual shapes samples
    its world-space field again at every pose (:func:`pose_ambient`)."""
    return {"oof_directions": max(64, options.oof_directions // factor ** 2),
            "oof_shells": max(8, options.oof_shells // factor)}


def has_remainder(world: World) -> bool:
    """Whether ``world`` has a light whose reduction leaves an SH remainder."""
    return any(lt.type in ENV_TYPES for lt in world.lights)


def prepare_ambient(world: World, view: SceneView, options) -> AmbientOcclusion:
    """The occluder, occlusion field and AO distance of ``world`` (``view``: a loaded view
    with its virtual shapes); :meth:`AmbientOcclusion.none` when there is nothing to occlude
    (no virtual shape, or no environment light) — then the field is not sampled."""
    if not world.has_virtual or not has_remainder(world):
        return AmbientOcclusion.none()
    occluder = make_occluder(world)
    oof = field_from_options(world, options) if occluder is not None else None
    rho = virtual_albedo(world) if options.ambient_bounce else np.zeros(3)
    return AmbientOcclusion(occluder, oof, ao_distance(world, view), rho)


def virtual_albedo(world: World) -> np.ndarray:
    """``ρ_v`` of Eq. 3 (RGB): the mean over the virtual shapes of their diffuse
    reflectance — ``diffuse``: the albedo (a texture's mean), ``phong``: ``kd + ks`` (its
    directional-hemispherical reflectance at normal incidence, the specular lobe folded in
    as diffuse); other materials 0 (no fill)."""
    from arlight.io.images import mean_linear

    out = []
    for s in world.virtual_shapes:
        p = s.material.params
        if s.material.type == "diffuse":
            out.append(mean_linear(p["texture"]) if p.get("texture") else p["albedo"])
        elif s.material.type == "phong":
            out.append(np.add(p["kd"], p["ks"]))
        else:
            out.append(np.zeros(3))
    return np.clip(np.mean(np.asarray(out, np.float64), axis=0), 0.0, 1.0) if out \
        else np.zeros(3)


def ao_distance(world: World, view: SceneView) -> float:
    """The AO ray length (m): the diagonal of the virtual objects' bounding box (∞ without
    virtual objects)."""
    b = virtual_bounds(world, view) if world.has_virtual else None
    return float(np.linalg.norm(b[1] - b[0])) if b is not None else math.inf


def pose_ambient(amb: AmbientOcclusion, before: World, after: World, view: SceneView,
                 options) -> AmbientOcclusion | None:
    """``amb`` of ``before`` for ``after`` (the same world posed otherwise, ``view`` already
    moved): the occluder and field follow the pose (:func:`~arlight.realtime.oof.
    move_occluder`, :func:`~arlight.realtime.oof.pose_field`: an object-space field is
    looked up through the new pose, a world-space one sampled again — only when a virtual
    shape moved). None when the occluder cannot follow (prepare again)."""
    if amb.occluder is None or not virtual_moved(before, after):
        return amb  # nothing virtual moved (a still frame): a world-space field stays valid
    ok, occluder = move_occluder(amb.occluder, before, after)
    if not ok:
        return None
    oof = pose_field(amb.field, after, options)
    if oof is None and options.oof:
        oof = field_from_options(after, options)
    return replace(amb, occluder=occluder, field=oof, distance=ao_distance(after, view))


def real_ambient_loss(amb: AmbientOcclusion, lights: LightSet, p: mi.Point3f,
                      n: mi.Vector3f, active: mi.Bool) -> mi.Color3f:
    """``−ΔE_a`` of Eq. 1 (W/m², ≥ 0): the ambient irradiance the virtual objects block at
    the ``active`` lanes (real surface points ``p``, unit normals ``n``), clipped to the
    unoccluded ``E_a(n)``; zero on other lanes and outside the field's outermost shell
    (only lanes inside it are looked up)."""
    amb_sh = np.asarray(lights.ambient_sh, np.float64)
    if amb.field is None or not np.any(amb_sh):
        return mi.Color3f(0.0)
    oof = amb.field
    light = amb_sh.copy()
    light[0] *= 1.0 - amb.albedo  # Eq. 3: L_a − ρ_v L̄, L̄ = L_00 Y_00
    # opaque: one kernel for every pose of the field
    c = mi.Point3f(*[dr.opaque(mi.Float, float(x)) for x in oof.world_centre])
    near = active & (dr.norm(p - c) < dr.opaque(mi.Float, oof.world_r_max))

    def loss(pc: mi.Point3f, nc: mi.Vector3f) -> mi.Color3f:
        e_a = dr.maximum(ambient_irradiance_dr(lights, nc), 0.0)
        return dr.minimum(oof.occluded_irradiance(light, pc, nc), e_a)

    return on_active(loss, p, n, near)


def virtual_ambient(amb: AmbientOcclusion, lights: LightSet, p: mi.Point3f, n: mi.Vector3f,
                    rays: int, seed: int = 0) -> mi.Color3f:
    """Eq. 2 on every lane (virtual surface points ``p``, unit normals ``n``): ``A(x) E_a(n)``
    with ``rays`` AO rays against the virtual shapes (W/m²; ``E_a(n)`` unoccluded when
    there is no occluder or ``rays`` is 0)."""
    e_a = ambient_irradiance_dr(lights, n)
    if amb.occluder is None or rays <= 0 or not np.any(lights.ambient_sh):
        return e_a
    a = ambient_occlusion(amb.occluder, p, n, rays, amb.distance, seed)
    # Eq. 3 on the object: the blocked directions see the object itself, radiance ρ_v L̄
    fill = np.pi * amb.albedo * np.asarray(lights.ambient_sh, np.float64)[0] * Y00
    return e_a * a + mi.Color3f(*opaques(fill)) * (1.0 - a)


__all__ = ["AMBIENT_OPTIONS", "ENV_TYPES", "AmbientOcclusion", "ambient_drag_options",
           "ao_distance",
           "has_remainder", "pose_ambient", "prepare_ambient", "real_ambient_loss",
           "virtual_ambient"]
