"""``dlpv``: Delta Light Propagation Volumes (Franke 2013, ISMAR; thesis §5.3).

Per frame and per reduced light (:mod:`arlight.realtime.light_reduction`):

1. two reflective shadow maps from the same light rays, ``R_ρ`` (mixed scene) and ``R_µ``
   (real proxy only) (§4.3); ``R_µ`` is cast once when the world is prepared (the proxy and
   the lights stay put) and a frame casts only the rays that cross the virtual objects'
   bounding box;
2. **indirect split injection** into the delta volume ``V_Δ`` (Eq. 13): every ``R_ρ`` texel's
   VPL ``Φ_p/π <n_p, ω>+`` (Eq. 12) added, every ``R_µ`` texel's subtracted, texels that see
   the same surface in both maps eliminated; each VPL moved half a cell along its normal
   before its cell is chosen (§4.3.1);
3. **direct injection** (§4.3.2): the same texels again, with the light's flux ``Φ_r`` as a
   lobe along the light's direction of travel (the negative incident direction), moved half a
   cell towards the light — direct antiradiance;
4. the regular LPV ``V_ρ`` injected with ``R_ρ``'s VPLs (indirect light on the virtual
   object);
5. [KD10] propagation of both volumes (32 steps), with the directional-derivative dampening
   of §4.4 (option); ``V_Δ``'s ``+R_ρ`` VPLs, the objects' own bounce, in a volume of their
   own, undamped (issue #33, :func:`delta_dampening`);
6. composition (Alg. 1, thesis §5.3.4): virtual pixels ``ρ/π (E_direct + E_{V_ρ} +
   E_ambient)`` with shadow rays to the reduced lights; real pixels ``B + ρ/π E_{V_Δ}``,
   the volume evaluated with the inverse normal (cosine-convolved, :func:`~arlight.realtime.
   sh_volume.query_irradiance`) at the point moved half a cell along its normal.

Issue #33 defaults (chosen on 12 training worlds): ``direct = rays`` — the reduced lights'
direct change on real pixels from shadow rays in the mixed and the real scene
(:func:`~arlight.realtime.shading.direct_change`, soft for extended lights:
``shadow_samples``) in place of step 3's lobes (``direct = volume``, Franke's blurred
shadow); ``lost_bounce`` off — ``V_Δ`` without the ``−R_µ`` VPLs of step 2 (an LPV reads a
real surface's own VPLs on itself); ``real_albedo = photo`` (the change as a ratio of the
photograph, :mod:`arlight.realtime.real_lane`).

The volume is a world-axis-aligned cube around the virtual objects, ``volume_scale`` (2) ×
their largest bounding-box edge, on a fixed world lattice (``fixed_lattice``,
:func:`~arlight.methods.fragments.volume_grid`). Injection is normalised by
:func:`injection_scales` (direct lobes ÷ the lit-plane response, VPLs ÷ the one-VPL
response); ``geometry_volume`` adds [KD10]'s blocking. Layers: ``mixed``
is the shaded virtual object on virtual pixels and ``B + delta`` elsewhere (the method has no
``I_r``); ``delta`` is the DLPV term; ``mask`` the G-buffer coverage.

Stats: ``time_gbuffer``, ``time_rsm``, ``time_inject_rho``, ``time_inject_delta_indirect``,
``time_inject_delta_direct``, ``time_propagate_rho``, ``time_propagate_delta``,
``time_shade``, ``time_assemble`` (s); ``lights``, ``vpls_delta`` (texels injected into
``V_Δ``), ``volume_cell`` (m). See ``docs/methods/dlpv.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews, build_views
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
)
from arlight.methods.fragments import (
    AA_GBUFFER_SPP,
    GBUFFER_FRAME_OPTIONS,
    LATTICE_OPTIONS,
    REDUCTION_OPTIONS,
    drag_gbuffer_spp,
    follow_volume,
    gbuffer_options,
    volume_grid,
)
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.ambient import (
    AMBIENT_OPTIONS,
    AmbientOcclusion,
    ambient_drag_options,
    pose_ambient,
    prepare_ambient,
    real_ambient_loss,
)
from arlight.realtime.gbuffer import GBuffer, assemble, render_gbuffer
from arlight.realtime.ibl_shading import probe_drag_options
from arlight.realtime.light_reduction import REDUCIBLE_LIGHTS, LightSet, reduce_lights
from arlight.realtime.object_shading import (
    OBJECT_OPTIONS,
    ObjectLight,
    pose_object_light,
    prepare_object_light,
    shade_objects,
)
from arlight.realtime.real_lane import REAL_LANE_OPTIONS, real_albedo
from arlight.realtime.rsm import (
    RealMaps,
    RSMPair,
    check_memory,
    moved_maps,
    real_maps,
    rsm_pair,
    same_grid,
)
from arlight.realtime.sh_volume import (
    Grid,
    SHVolume,
    face_transmittance,
    inject,
    plane_response,
    point_response,
    propagate,
    query_irradiance,
    query_irradiance_compact,
    transmittance_dr,
)
from arlight.realtime.shading import (
    direct_terms_gbuffer,
    virtual_bounds,
)
from arlight.realtime.voxels import blocking_potential, shape_triangles
from arlight.scene.model import FrameView, World
from arlight.timing import StageTimer

CALIBRATE = 1.0
"""Default ``calibrate``, an extra divisor of ``V_Δ`` reads on top of the derived
normalisation (:func:`injection_scales`; issue #33: 1, none)."""
CALIBRATE_RHO = 1.0
"""Default ``calibrate_rho``, an extra divisor of ``V_ρ`` reads (1: none)."""
DIRECT_MODES = ("volume", "rays", "none")
"""Values of the ``direct`` option: where the direct change on real surfaces comes from."""

OPTIONS: dict[str, Field] = {
    "volume_size": Field("int", 32, "cells per edge of V_Δ and V_ρ (Franke: 32³)", "cells",
                         min=2, max=256),
    "steps": Field("int", 32, "propagation iterations (Franke: 32)", "", min=0, max=1024),
    "rsm_size": Field("int", 256, "RSM resolution per light, texels per side (Franke: 512²; "
                      "256 since issue #33: V_Δ carries the objects' bounce alone, and 512 "
                      "changed no training world by more than 0.02 dB at 3× the maps' cost)",
                      "texels", min=1, max=16384),
    "dampening": Field("bool", True, "directional-derivative dampening of shadow bleeding "
                       "(Franke §4.4)"),
    "dampen_bounce": Field("bool", False, "apply the dampening to the virtual objects' own "
                           "VPLs (+R_ρ, their bounce on the real scene) too, in one V_Δ "
                           "propagation as before issue #33 (their bounce then came out at "
                           "0.26× a path-traced one; off: they propagate undamped in a volume "
                           "of their own; docs/methods/dlpv.md)"),
    "direct": Field("choice", "rays", "the reduced lights' direct change on real surfaces "
                    "(their shadows): `volume`: direct light/antiradiance lobes injected into "
                    "V_Δ (T_Δ¹, Franke §4.3.2: a blurred shadow); `rays`: shadow rays in the "
                    "mixed and the real scene per real pixel (as dir; V_Δ keeps the indirect "
                    "change); `none`: indirect change only", choices=DIRECT_MODES),
    "lost_bounce": Field("bool", False, "inject the −R_µ VPLs into V_Δ: the real surfaces' "
                         "bounce that the virtual objects take away (§4.3.1); off: V_Δ "
                         "holds the objects' own bounce (+R_ρ) and the direct lobes only"),
    "calibrate": Field("float", CALIBRATE, "extra divisor of V_Δ reads on top of the derived "
                       "normalisation (direct lobes / the plane response, VPLs / the point "
                       "response; docs/methods/dlpv.md); 1: none", "", min=0.0, max=100.0,
                       exclusive_min=True),
    "calibrate_rho": Field("float", CALIBRATE_RHO, "extra divisor of V_ρ reads (the indirect "
                           "light on the virtual objects); 1: none", "", min=0.0, max=100.0,
                           exclusive_min=True),
    "geometry_volume": Field("bool", False, "KD10 fuzzy blocking: a geometry volume of the "
                             "real proxy and the virtual objects attenuates propagation, so "
                             "light does not leak through objects and thin walls (off: it "
                             "cost 0.2 dB on the training worlds, docs/methods/dlpv.md)"),
    "volume_scale": Field("float", 2.0, "volume edge / largest edge of the virtual objects' "
                          "bounding box (Franke: 2)", "", min=1.0, max=100.0),
    **AMBIENT_OPTIONS,
    **OBJECT_OPTIONS,
    **REAL_LANE_OPTIONS,
    **LATTICE_OPTIONS,
    **REDUCTION_OPTIONS,
    **gbuffer_options(AA_GBUFFER_SPP),
}


def drag_options(options: Options, factor: int) -> dict[str, int]:
    """Options of a studio frame at 1/``factor`` of the size while dragging (issue #32): the
    RSM side, the volume's cells per edge and the propagation steps divided by ``factor``
    (at least 64 texels, 16 cells, 8 steps), one G-buffer sample
    (:func:`~arlight.methods.fragments.drag_gbuffer_spp`): RSMs, injection and
    propagation do not shrink with the image otherwise; the ambient occlusion field's rays
    and shells too (:func:`~arlight.realtime.ambient.ambient_drag_options`); the objects'
    bounce probe is not traced again per pose
    (:func:`~arlight.realtime.ibl_shading.probe_drag_options`)."""
    return {"rsm_size": max(64, options.rsm_size // factor),
            **drag_gbuffer_spp(options, factor),
            "volume_size": max(16, options.volume_size // factor),
            "steps": max(8, options.steps // factor), **ambient_drag_options(options, factor),
            **probe_drag_options(options, factor)}


SPEC = MethodSpec(
    name="dlpv",
    description="Delta Light Propagation Volumes (Franke 2013): one SH volume of the change "
                "of light, real time.",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, materials=frozenset({"diffuse", "phong"}),
                              lights=REDUCIBLE_LIGHTS),
    drag_options=drag_options,
    frame_options=GBUFFER_FRAME_OPTIONS,
)


@dataclass
class DLPVData:
    """What ``prepare_world`` keeps: the world, its Mitsuba views, the reduced lights, the
    volume grid, the scales of ``V_Δ`` and ``V_ρ`` reads (:func:`read_scales`), the real
    proxy's RSMs (grid and maps None without virtual objects), the injection scales
    (:func:`injection_scales`: direct lobes, VPLs) and the geometry volume: the real proxy's
    blocking potential (kept while the grid stays) and the face transmittances of the mixed
    scene (None with ``geometry_volume`` off)."""

    world: World
    views: SceneViews
    lights: LightSet
    grid: Grid | None
    read_scale: float = 1.0
    real_maps: RealMaps | None = None
    rho_scale: float = 1.0
    inject_scale: tuple[float, float] = (1.0, 1.0)
    real_blocking: np.ndarray | None = None
    transmittance: list | None = None
    ambient: AmbientOcclusion = field(default_factory=AmbientOcclusion.none)
    ao_rays: int = 0
    direct: str = "volume"
    real_albedo: str = "proxy"
    shadow_samples: int = 1
    objects: ObjectLight | None = None


@dataclass
class Volumes:
    """The volumes of one frame and the masks of the VPL texels that went into ``V_Δ``."""

    delta: SHVolume | None
    rho: SHVolume | None
    injected: list

    @property
    def vpls_delta(self) -> int:
        """VPL texels injected into ``V_Δ`` (waits for the injection kernels)."""
        return injected_count(self.injected)


def read_scales(options: Options) -> tuple[float, float]:
    """``(1/calibrate, 1/calibrate_rho)``: the factors of ``V_Δ`` and ``V_ρ`` reads."""
    return 1.0 / float(options.calibrate), 1.0 / float(options.calibrate_rho)


def injection_scales(options: Options) -> tuple[float, float]:
    """The derived normalisation (issue #33): ``(1/plane_response, 1/point_response)``, the
    factors of the flux of the direct lobes and of the VPLs at injection.

    Both injections are cosine lobes, but they model different light: a direct lobe is a
    sample of a surface lit densely, cell by cell — an LPV reading such a layer at a cell of
    it counts the neighbours' lobes too and over-reads the irradiance by
    :func:`~arlight.realtime.sh_volume.plane_response` (1.92 at 32³, 32 steps) — while a VPL
    is a point emitter, which the LPV reads at 2–4 cells as
    :func:`~arlight.realtime.sh_volume.point_response` (0.88) × ``Φ cos θ/(π r²)``. Both are
    computed from the propagation operator at the options' size, steps and dampening, no
    scene. Propagation is linear (dampening depends on ratios only), so scaling the injected
    flux is scaling what is read.

    The VPLs' divisor is the cell-centre response (``offset`` 0), not the one derived with
    this method's half-cell injection and read offsets (1.71, ``offset =
    VPL_OFFSET``), under which one VPL obeys the inverse-square law at 2.5–4 cells (under
    0.88 it reads 1.9× too bright there, tests/realtime/test_lpv_reference.py): the LPV
    loses a VPL's light beyond 4 cells, where much of an object's bounce lands, and 0.88's
    near-field excess makes up for it — 1.71 cost 0.09 dB on the training worlds and halved
    the cube's bleed against a path tracer (issue #33, docs/methods/dlpv.md "One VPL and
    the far field")."""
    n, k, d = options.volume_size, options.steps, options.dampening
    return 1.0 / plane_response(n, k, d), 1.0 / point_response(n, k, d, offset=0.0)


def virtual_triangles(world: World) -> np.ndarray:
    """World-space triangles ``(F, 3, 3)`` of the virtual objects."""
    return np.concatenate([shape_triangles(s) for s in world.virtual_shapes])


def geometry_volume(world: World, grid: Grid, real: np.ndarray | None
                    ) -> tuple[np.ndarray, list]:
    """``(real blocking, transmittances)``: the real proxy's blocking potential on ``grid``
    (``real``, or computed when None) and the face transmittances of the mixed scene, the
    blocking of real and virtual surfaces added (clipped to 1), as :func:`~arlight.realtime.
    sh_volume.propagate` takes them."""
    if real is None:
        shapes = world.real_shapes
        real = (blocking_potential(np.concatenate([shape_triangles(s) for s in shapes]), grid)
                if shapes else np.zeros((grid.n + 1,) * 3 + (3,), np.float32))
    both = np.minimum(real + blocking_potential(virtual_triangles(world), grid), 1.0)
    return real, transmittance_dr(face_transmittance(both))


def prepare(world: World, options: Options) -> DLPVData:
    """Mitsuba views, reduced lights, the volume placement of ``world`` and its geometry
    volume."""
    check_memory(options.rsm_size)
    views = build_views(world)
    lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
    bounds = virtual_bounds(world, views.mixed) if world.has_virtual else None
    grid = None if bounds is None else volume_grid(bounds, options)
    if grid is None:
        return DLPVData(world, views, lights, None)
    k_delta, k_rho = read_scales(options)
    maps = real_maps(views, lights, grid, options.rsm_size, bounds)
    real, trans = geometry_volume(world, grid, None) if options.geometry_volume else (None,
                                                                                     None)
    return DLPVData(world, views, lights, grid, k_delta, maps, k_rho, injection_scales(options),
                    real, trans, prepare_ambient(world, views.mixed, options), options.ao_rays,
                    options.direct, options.real_albedo, options.shadow_samples,
                    prepare_object_light(world, views, options))


def pose(data: DLPVData, world: World, transforms: dict[str, np.ndarray], options: Options
         ) -> DLPVData | None:
    """``data`` (prepared for ``world`` in any pose) moved in place to
    ``world.posed(transforms)`` (issue #32): the shapes move in the Mitsuba views, the volume
    follows the objects' bounds, the proxy's RSMs are kept (cast again only for directional
    lights when the snapped volume moved, :func:`~arlight.realtime.rsm.moved_maps`). Bitwise
    the data :func:`prepare` makes of the posed world; None (nothing changed) when a real
    shape moves."""
    moved = follow_volume(data.views, data.grid, world, transforms, options)
    if moved is None:
        return None
    posed, grid, bounds = moved
    amb = pose_ambient(data.ambient, data.world, posed, data.views.mixed, options)
    if amb is None:
        return None
    if grid is None or data.real_maps is None:
        return replace(data, world=posed, ambient=amb)
    objects = pose_object_light(data.objects, posed, data.views, options)
    real, trans = None, None
    if data.real_blocking is not None:
        keep = data.real_blocking if same_grid(data.grid, grid) else None
        real, trans = geometry_volume(posed, grid, keep)
    return replace(data, world=posed, grid=grid, ambient=amb, objects=objects,
                   real_maps=moved_maps(data.real_maps, data.views, grid, bounds),
                   real_blocking=real, transmittance=trans)


def inject_delta(vol: SHVolume, pairs: list[RSMPair], direct: bool,
                 indirect: bool = True, scales: tuple[float, float] = (1.0, 1.0),
                 bounce: SHVolume | None = None, lost: bool = True) -> list[mi.Bool]:
    """Split injection into ``V_Δ`` (Eq. 13 and §4.3.2): ``+R_ρ``, ``−R_µ``. Texels that see
    the same surface in both maps cancel and are skipped (§4.3.1: "VPLs visible in both RSMs
    are eliminated"): only the texels whose mixed-scene hit is virtual are injected. Returns
    the injected-lane masks of the indirect lobes (see :func:`injected_count`). ``scales``:
    the flux factors of direct lobes and VPLs (:func:`injection_scales`); ``bounce`` (default
    ``vol``): the volume that receives the ``+R_ρ`` VPLs, the virtual objects' own bounce
    (:func:`delta_dampening`); ``lost`` False: the indirect ``−R_µ`` VPLs (the real
    surfaces' bounce the objects take away) are left out."""
    half = 0.5 * vol.grid.cell
    k_dir, k_ind = float(scales[0]), float(scales[1])
    masks = []
    for pair in pairs:
        if dr.width(pair.changed) == 0:  # this light does not see the virtual objects
            continue
        for r, sign in ((pair.rho_changed(), 1.0), (pair.mu_changed, -1.0)):
            if indirect and (lost or sign > 0):
                target = bounce if bounce is not None and sign > 0 else vol
                masks.append(inject(target, r.position, r.normal, r.flux_out * (sign * k_ind),
                                    r.valid, offset=r.normal * half))
            if direct:
                inject(vol, r.position, r.direction, r.flux_in * (sign * k_dir), r.valid,
                       offset=r.direction * (-half))
    return masks


def injected_count(masks: list[mi.Bool]) -> int:
    """How many lanes the masks of :func:`inject_delta` hold (waits for their kernels)."""
    return sum(int(dr.count(m)[0]) for m in masks if dr.width(m))


def inject_regular(vol: SHVolume, pairs: list[RSMPair], which: int = 0,
                   direct: bool = False, scales: tuple[float, float] = (1.0, 1.0)) -> None:
    """A regular LPV: every VPL of ``R_ρ`` (``which=0``) or ``R_µ`` (``which=1``), and with
    ``direct`` also the direct lobes; ``scales`` as :func:`inject_delta`."""
    half = 0.5 * vol.grid.cell
    for pair in pairs:
        r = pair.rho if which == 0 else pair.mu()
        inject(vol, r.position, r.normal, r.flux_out * float(scales[1]), r.valid,
               offset=r.normal * half)
        if direct:
            inject(vol, r.position, r.direction, r.flux_in * float(scales[0]), r.valid,
                   offset=r.direction * (-half))


def build_volumes(data: DLPVData, options: Options, timer: StageTimer | None = None
                  ) -> Volumes:
    """RSMs, injections and propagation of one frame (the stages of Franke Table 5.2)."""
    timer = timer or StageTimer()
    grid = data.grid
    if grid is None or not data.lights.lights:
        return Volumes(None, None, [])
    with timer.stage("rsm"):
        pairs = rsm_pair(data)
    k = data.inject_scale
    # V_ρ lights the virtual objects only; with the bounce probe their real-surface bounce
    # comes from the probe (arlight.realtime.object_shading), and V_ρ is not built
    need_rho = data.objects is None or not data.objects.probe
    v_rho = None
    if need_rho:
        with timer.stage("inject_rho"):
            v_rho = SHVolume.zeros(grid)
            inject_regular(v_rho, pairs, 0, scales=k)
    damp_bounce, damp_rest = delta_dampening(options)
    # without the −R_µ VPLs and the direct lobes V_Δ holds the objects' bounce alone: one
    # volume, propagated with the bounce's dampening (the empty rest is not propagated)
    bounce_only = not options.lost_bounce and options.direct != "volume"
    if bounce_only:
        damp_rest = damp_bounce
    split = damp_bounce != damp_rest
    with timer.stage("inject_delta_indirect"):
        v_delta = SHVolume.zeros(grid)
        v_bounce = SHVolume.zeros(grid) if split else None
        injected = inject_delta(v_delta, pairs, direct=False, scales=k, bounce=v_bounce,
                                lost=options.lost_bounce)
    if options.direct == "volume":
        with timer.stage("inject_delta_direct"):
            inject_delta(v_delta, pairs, direct=True, indirect=False, scales=k)
    trans = data.transmittance
    if v_rho is not None:
        with timer.stage("propagate_rho"):
            v_rho = propagate(v_rho, options.steps, options.dampening, transmittance=trans)
    with timer.stage("propagate_delta"):
        v_delta = propagate(v_delta, options.steps, damp_rest, transmittance=trans)
        if v_bounce is not None:
            v_bounce = propagate(v_bounce, options.steps, damp_bounce, transmittance=trans)
            v_delta = SHVolume(grid, [a + b for a, b in zip(v_delta.coeffs, v_bounce.coeffs,
                                                            strict=True)])
    return Volumes(v_delta, v_rho, injected)


def delta_dampening(options: Options) -> tuple[bool, bool]:
    """Whether ``V_Δ``'s ``+R_ρ`` VPLs (the virtual objects' own bounce) and the rest (the
    ``−R_µ`` VPLs and the direct lobes) are damped (issue #33): ``(dampening and
    dampen_bounce, dampening)``. The dampening (§4.4) is there against bleeding of the real
    surfaces' antiradiance ("bleeding out from below virtual objects"); in one volume its
    ratios are dominated by that antiradiance next to the object, and it removed 74 % of the
    object's bounce on the floor (tests/methods/test_dlpv_reference.py). When the two
    differ the ``+R_ρ`` VPLs propagate in a volume of their own whose sum with the rest is
    read as one. The real surfaces' ``−R_µ`` VPLs stay damped: undamped, a real surface's
    own VPLs light it (an LPV reads an emitting plane on itself at 1.4× its exitance, 1.1×
    damped, where 0 is right) and the cube's shadow came out 1.6× too deep."""
    return bool(options.dampening and options.dampen_bounce), bool(options.dampening)


def shade(data: DLPVData, gb: GBuffer, vols: Volumes, frame: np.ndarray | None = None
          ) -> tuple[mi.Color3f, mi.Color3f]:
    """Per-lane ``(virtual radiance, delta radiance)`` (Alg. 1 / Eqs. 5.14–5.16), with the
    SH ambient remainder occluded by the virtual objects (issue #33,
    :mod:`arlight.realtime.ambient`): weighted by their ambient occlusion on virtual lanes
    (Eq. 2 there), its blocked part subtracted on real lanes (Eq. 1, the occlusion field)."""
    virt = gb.virtual
    real = gb.valid & ~virt
    # opaque: one compiled kernel for every scale (benchmarks/tune_realtime.py sweeps them)
    k = dr.opaque(mi.Float, float(data.read_scale))
    k_rho = dr.opaque(mi.Float, float(data.rho_scale))
    half = 0.5 * data.grid.cell if data.grid is not None else 0.0

    def v_rho(idx: mi.UInt32, p: mi.Point3f, n: mi.Vector3f) -> mi.Color3f:
        """``V_ρ``'s indirect irradiance on the virtual lanes ([KD10]: half a cell out)."""
        return query_irradiance(vols.rho, p + n * half, n) * k_rho

    # the objects' own shading (arlight.realtime.object_shading; V_ρ is None with the probe)
    mixed = shade_objects(data.objects, data.world, data.views, data.lights, data.ambient,
                          gb, None if vols.rho is None else v_rho, data.ao_rays)
    e_delta = -real_ambient_loss(data.ambient, data.lights, gb.position, gb.normal, real)
    e_vol = None
    if vols.delta is not None:
        q = gb.position + gb.normal * half
        e_vol = k * query_irradiance_compact(vols.delta, q, gb.normal, real)
    # the direct change's shadow rays also give E_r's direct part (no rays of its own),
    # the mixed scene's only where they can meet the objects (exact), the real scene's
    # where the change may be non-zero (there, or where the other terms are)
    if data.direct == "rays":
        other = dr.any(e_delta != 0.0)
        if e_vol is not None:
            other |= dr.any(e_vol != 0.0)
        terms = direct_terms_gbuffer(data.views, data.lights, gb, real, data.shadow_samples,
                                     data.world,
                                     real & other if frame is not None else mi.Bool(False))
        e_delta += terms.change
    else:
        terms = None
    if e_vol is not None:
        e_delta += e_vol
    rho = gb.albedo * (1.0 / np.pi)
    # the photograph's albedo where the change is not zero (elsewhere it multiplies zero:
    # no shadow rays for E_r outside the volume and the shadows)
    rho_real = rho if frame is None else real_albedo(
        data.real_albedo, data.views, data.lights, frame, gb,
        real & dr.any(e_delta != 0.0), None,
        None if terms is None else terms.real) * (1.0 / np.pi)
    delta = dr.select(real, rho_real * e_delta, mi.Color3f(0.0))
    dr.eval(mixed, delta)
    return mixed, delta


def compose(data: DLPVData, gb: GBuffer, vols: Volumes, view: FrameView,
            timer: StageTimer | None = None) -> Layers:
    """Shading and composition of one frame from its G-buffer and volumes (the stages after
    :func:`build_volumes`; only these read ``data.read_scale`` and ``data.rho_scale``, so
    ``benchmarks/tune_realtime.py`` builds the volumes once per world and composes each
    calibration candidate)."""
    timer = timer or StageTimer()
    with timer.stage("shade"):
        mixed, delta = shade(data, gb, vols, view.frame)
    with timer.stage("assemble"):
        stats = {"lights": float(len(data.lights.lights)),
                 "vpls_delta": float(vols.vpls_delta),
                 "volume_cell": data.grid.cell if data.grid else 0.0}
        layers = assemble(gb, view.frame, mixed, delta, stats)
    if not data.world.has_virtual:
        assert not np.any(layers.delta), "dlpv: delta must vanish without virtual objects"
    return layers


class DLPVMethod(BaseMethod):
    """Delta Light Propagation Volumes (Franke 2013)."""

    spec = SPEC
    incremental_pose = True

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> DLPVData:
        return prepare(world, options)

    move = staticmethod(pose)  # in place; a moved real shape prepares again

    def relit(self, data: DLPVData, world: World, options: Options) -> DLPVData | None:
        """Light update (issue #32, :meth:`BaseMethod.relight`): the views' emitters set in
        place, the lights reduced again and the proxy's RSMs cast again into the kept
        volume; the volume placement and the scales are kept."""
        from arlight.methods.base import relight_views

        if not relight_views(data.views, data.world.lights, world.lights):
            return None
        lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
        if data.real_maps is None:
            return replace(data, world=world, lights=lights)
        return replace(data, world=world, lights=lights,
                       objects=prepare_object_light(world, data.views, options),
                       real_maps=real_maps(
            data.views, lights, data.grid, options.rsm_size, data.real_maps.box))

    def render_view(self, data: DLPVData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        with timer.stage("gbuffer"):
            gb = render_gbuffer(data.views.mixed, view.camera, options.gbuffer_spp,
                                settings.seed)
        vols = build_volumes(data, options, timer)
        return compose(data, gb, vols, view, timer)


__all__ = ["CALIBRATE", "CALIBRATE_RHO", "DLPVData", "DLPVMethod", "OPTIONS", "RealMaps",
           "SPEC", "Volumes", "build_volumes", "compose", "geometry_volume", "inject_delta",
           "inject_regular", "injected_count", "injection_scales", "prepare", "read_scales",
           "real_maps", "rsm_pair", "delta_dampening"]
