"""``dvct``: Delta Voxel Cone Tracing (Franke 2014, thesis §5.4).

Per frame (stages of thesis Table 5.6):

1. **G-buffer** (ray cast) and, per reduced light, the RSM pair ``R_ρ`` / ``R_µ``
   (:mod:`arlight.realtime.rsm`, the texels that see the virtual object cast twice);
2. **voxelisation** into ``V_η`` (occupancy ``α`` and normal, conservative,
   :func:`arlight.realtime.voxels.voxelize`): the real proxy once per prepared world, the
   virtual objects every frame; ``α_all = max(α_real, α_virtual)`` and ``α_real`` are kept;
3. **split injection** (Eq. 5.17): a texel whose mixed-scene hit is real cancels and injects
   nothing; a virtual texel injects ``+Φ_ρ/π`` at the virtual surface and ``−Φ_µ/π`` at the
   real surface ``R_µ`` sees there (now in its shadow) into ``V_Δ``; ``V_ρ`` receives every
   ``R_ρ`` texel (the first bounce that lights the virtual objects). VPLs move half a cell
   along their normal before their cell is chosen (as ``dlpv``);
4. **filtering**: mip chains of ``V_η`` (α included), ``V_Δ`` and ``V_ρ``;
5. **cone tracing** (:func:`arlight.realtime.voxels.trace_cones`, Eq. 5.18–5.19 in the
   standard front-to-back form) at full or reduced resolution (``cone_scale``; reduced: from
   the first G-buffer sample of every ``k``-th pixel), then edge-aware upsampling to every
   G-buffer sample (``gbuffer_spp`` per pixel):

   * real pixels: nine diffuse cones into ``V_Δ`` (Eq. 5.21), on specular materials one cone
     along the reflected view direction (Eq. 5.22, aperture from the roughness), and with
     ``direct = cones`` one shadow cone per light (Eq. 5.20, aperture from the light's size;
     by default, ``direct = rays``, the shadows are traced per G-buffer sample instead,
     :func:`arlight.realtime.shading.direct_change`, as ``dir`` and ``dlpv``; issue #33);
   * virtual pixels: nine diffuse cones and one specular cone into ``V_ρ`` (Eq. 5.24–5.25);

6. **shading and composition** (§5.4.4): real pixels ``B + ρ/π · ΔE + k_s C_Δ,spec −
   h α_spec B``; virtual pixels ``ρ/π (E_direct + E_cones + E_ambient (1 − AO_virtual)) +`` GGX
   specular (Eq. 5.23, direct from the reduced lights with shadow rays; ``D`` and ``G1`` of
   :mod:`arlight.realtime.ibl_shading`) ``+ F C_ρ,spec``.

**The real-occluder question** (the thesis leaves it open): ``V_η`` holds the real proxy,
whose shadows are already in the photograph. Cones accumulate, besides ``α_all`` and
``α_real``, the transmittance ``k`` the virtual objects leave in the space the real geometry
leaves free (per sample ``(1 − α_all)/(1 − α_real)``, so a cone's false self-occlusion by
the receiving surface cancels); the shadow term is ``−(1 − k) E_i^µ`` with ``E_i^µ`` the
light's irradiance in the real proxy (one shadow ray): a real occluder alone darkens
nothing, and a virtual object inside a real shadow darkens no further.

**Occlusion weighting of reflections** (§5.4.2: "the sampled visibility α from C_Δ is used to
weight the contribution in the background image"): on a real specular pixel the background's
reflected part is hidden by the virtual occlusion along the specular cone,
``−h · (1 − k) · B`` with ``h`` the specular share of the material (1 for mirrors
and rough conductors, ``|k_s| / (|k_s| + |k_d|)`` for Phong, 0 for diffuse), and the
virtual object's first bounce ``k_s C_Δ`` takes its place.

**Ambient** (the SH remainder of the light reduction): the diffuse cones' added occlusion
also removes the ambient light the virtual objects block, ``−ρ/π E_amb(n)/π Σ w_k
(1 − k)_k`` (the AO-like term of thesis §5.4.6, ours for the delta).

Layers: ``mixed`` is the shaded virtual object on virtual pixels and ``B + delta`` elsewhere;
``delta`` is the DVCT correction of the real pixels; ``mask`` the G-buffer coverage.
Stats: ``time_gbuffer``, ``time_rsm``, ``time_voxelize``, ``time_inject``, ``time_filter``,
``time_cones``, ``time_upsample``, ``time_shade``, ``time_assemble`` (s); ``lights``,
``vpls_delta``, ``voxels``, ``volume_cell`` (m), ``cone_lanes``. See
``docs/methods/dvct.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import ROLE_REAL, ROLE_VIRTUAL, SceneViews, build_views
from arlight.backend.reproject import Reprojector
from arlight.errors import InputError
from arlight.jit import aligned, opaque, opaques
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
    place_views,
)
from arlight.methods.fragments import (
    AA_GBUFFER_SPP,
    GBUFFER_FRAME_OPTIONS,
    REDUCTION_OPTIONS,
    drag_gbuffer_spp,
    gbuffer_options,
    volume_grid,
)
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.ambient import virtual_albedo
from arlight.realtime.exact_sum import scatter_sums_exact
from arlight.realtime.gbuffer import (
    GBuffer,
    assemble,
    facing,
    render_gbuffer,
    surface_albedo,
)
from arlight.realtime.ibl_shading import (
    MipEnvironment,
    SpecularTables,
    dfg_table,
    environment_map,
    ggx_d,
    prefilter_ggx,
    smith_g1,
    specular_split_sum,
    specular_tables,
)
from arlight.realtime.light_reduction import REDUCIBLE_LIGHTS, LightSet, ReducedLight, reduce_lights
from arlight.realtime.mirror_rays import MirrorLight, mirror_rays
from arlight.realtime.photo_albedo import photo_albedo
from arlight.realtime.real_lane import REAL_LANE_OPTIONS
from arlight.realtime.rsm import RealMaps, RSMPair, moved_maps, real_maps, rsm_pair, same_grid
from arlight.realtime.rsm import check_memory as check_rsm_memory
from arlight.realtime.sh_volume import Grid, cell_index
from arlight.realtime.shading import (
    ambient_irradiance_dr,
    direct_irradiance,
    direct_irradiance_compact,
    direct_terms_gbuffer,
    on_active,
    split_lights,
    virtual_bounds,
)
from arlight.realtime.shadow_reach import bounding_ball
from arlight.realtime.voxels import (
    ANISO_CHANNELS,
    COVER_CHANNELS,
    LEVEL_BIAS,
    SHELLS,
    ConeResult,
    ConeVolumes,
    LatticeVoxels,
    MipVolume,
    Voxels,
    aniso_lookup,
    build_mips,
    check_memory,
    cover_level0,
    eta_level0,
    frame_box,
    shape_triangles,
    trace_cones,
    voxelize,
)
from arlight.scene.model import FrameView, World
from arlight.sphere.sh import Y00, band_of_each_coeff, clamped_cosine_band, order_of
from arlight.timing import StageTimer

OPTIONS: dict[str, Field] = {
    "volume_size": Field("int", 128, "cells per edge of V_η, V_Δ, V_ρ, a power of two "
                         "(Franke: 256³)", "cells", min=2, max=1024),
    "rsm_size": Field("int", 512, "RSM resolution per light, texels per side (Franke: 1024²)",
                      "texels", min=1, max=16384),
    "volume_scale": Field("float", 2.0, "volume edge / largest edge of the virtual objects' "
                          "bounding box (Franke: 2)", "", min=1.0, max=100.0),
    "cone_scale": Field("int", 2, "cones traced on every k-th pixel per direction, then "
                        "edge-aware upsampling (1: full resolution)", "pixels", min=1, max=8),
    "diffuse_aperture_deg": Field("float", 60.0, "full aperture σ of the 9 diffuse cones "
                                  "(ours; the thesis gives none)", "deg", min=0.0, max=120.0,
                                  exclusive_min=True),
    "specular_min_aperture_deg": Field("float", 4.0, "smallest full aperture β of a "
                                       "specular cone (mirrors); otherwise 2·atan(GGX α)",
                                       "deg", min=0.0, max=120.0, exclusive_min=True),
    "directional_aperture_deg": Field("float", 0.53, "full shadow-cone aperture γ of a "
                                      "directional light (the sun: 0.53°)", "deg", min=0.0,
                                      max=90.0, exclusive_min=True),
    "point_light_radius": Field("float", 0.0, "radius given to point and spot lights for "
                                "their shadow cone (0: hard shadows)", "m", min=0.0,
                                max=100.0),
    "anisotropic": Field("bool", False, "V_Δ/V_ρ hold the Lambertian intensity towards "
                         "the 6 axis directions (issue #33: isotropic cells show a cube's lit "
                         "top to the floor beside it, its red bounce 4.1× a path tracer's, "
                         "0.66× anisotropic); off (chosen on training worlds: anisotropic "
                         "lost 0.26 dB median changed_psnr on 6, the bounce then too dark, "
                         "tests/methods/test_dvct_reference.py): one isotropic Φ/π per cell, "
                         "as Franke"),
    "occluded_bounce": Field("bool", False, "real receivers also lose the first bounce the "
                             "virtual objects hide from them: diffuse cones on real pixels "
                             "gather Δ·k − (1 − k)·µ = Δ − (1 − k)·ρ per sample (Eq. 5.27's "
                             "C_ρ − C_µ − C_Δ; issue #33); off: Δ·k as Franke (chosen on "
                             "training worlds: with anisotropic, no change of the median "
                             "on 6)"),
    "directional_occupancy": Field("bool", False, "radiance cones see a cell's occupancy "
                                   "along their direction, Σ_a |ω_a| cover_a (a sheet "
                                   "seen at θ covers cos θ; issue #33); shadow cones keep the "
                                   "isotropic α. Off: with the other issue-#33 options it "
                                   "lost 0.15 dB median on 6 training worlds "
                                   "(docs/methods/dvct.md)"),
    "virtual_self_occlusion": Field("bool", True, "diffuse cones on virtual pixels are "
                                    "attenuated by all geometry (α_all); off: by the real "
                                    "geometry only (α_real) — the receiving object's own "
                                    "voxels, which a 60° ring cone's footprint always "
                                    "touches, no longer hide its bounce (issue #33: cube's "
                                    "own bounce 0.52 → 0.67 of Mitsuba's; on, as Franke: "
                                    "off with the other issue-#33 options lost 0.15 dB "
                                    "median on 6 training worlds)"),
    "photo_albedo": Field("bool", True, "real pixels change by ρ̂/π ΔE with the albedo "
                          "read from the photograph, ρ̂ = clip(π B / E_r, 0, 1) "
                          "(arlight.realtime.photo_albedo; issue #33: the shadow as a ratio of "
                          "the light the pixel receives, right on textures the proxy "
                          "averaged). On since the shadows come from rays and V_Δ holds no "
                          "−R_µ (training:24, 11 dvct worlds: with direct = rays and "
                          "lost_bounce off +0.40 dB median changed_psnr, 10 of 11 gain, worst "
                          "±0; alone, before, +0.02 and worst −0.59: the floor's negative "
                          "self-bounce, scaled by a high ρ̂, made shadows too deep); off: the "
                          "proxy's albedo, as Franke"),
    "direct": Field("choice", "rays", "the reduced lights' direct change on real pixels (the "
                    "virtual objects' shadows): `rays`: shadow rays in the mixed and the real "
                    "scene per G-buffer sample, soft over an extended light with "
                    "shadow_samples (arlight.realtime.shading.direct_change, as dir and dlpv; "
                    "issue #33); `cones`: one shadow cone per light through V_η (Eq. 5.20, "
                    "Franke), at the cones' resolution", choices=("rays", "cones")),
    "shadow_samples": REAL_LANE_OPTIONS["shadow_samples"],
    "lost_bounce": Field("bool", False, "inject the −R_µ VPLs into V_Δ (Eq. 5.17, Franke): "
                         "the real surfaces' bounce the virtual objects take away; off: V_Δ "
                         "holds the objects' own bounce (+R_ρ) alone (issue #33: a real "
                         "receiver's diffuse cones read the −R_µ VPLs of its own shadowed "
                         "surface — a floor cannot light itself, yet its shadow came out "
                         "20–40 % too deep, held-out world-1000002 −4.6 dB against 2f93175; "
                         "as dlpv's lost_bounce)"),
    "surround_rays": Field("int", 16, "rays per virtual cone lane (cone_scale > 1; per "
                           "pixel, split over its G-buffer samples, at cone_scale 1) that "
                           "find the real proxy around it for the SH remainder and the far "
                           "bounce (arlight.methods.dvct.real_surround), cosine-distributed "
                           "(Vogel's spiral); 0: one ray along each of the nine diffuse "
                           "cones' axes (chosen on training worlds, issue #33: with "
                           "far_bounce, 16 rays +0.46 dB changed PSNR on world-0 where the "
                           "nine axes lost 0.51)", "", min=0, max=1024),
    "far_bounce": Field("bool", True, "virtual pixels see the real surfaces beyond the "
                        "volume lit: a surround ray (surround_rays) that hits one where the "
                        "camera does not see it takes its ρ/π E_direct (the reduced lights, "
                        "shadow rays in the mixed scene) besides ρ_r L̄, and the surround is "
                        "traced without an SH remainder too (issue #33: in a room lit by a "
                        "small lamp a virtual object got none of the walls' bounce); off: "
                        "ρ_r L̄ alone, and no surround without a remainder"),
    "back_faces": Field("bool", False, "dim V_Δ/V_ρ cells seen from behind their V_η normal "
                        "(costs a third more cone gathers; no gain on the suite)"),
    "diffuse_cones": Field("bool", True, "trace the 9 diffuse cones (T_Δ², Eq. 5.21; "
                           "off: shadows and reflections only)"),
    "specular_cones": Field("bool", True, "trace the specular cone on specular materials "
                            "(Eq. 5.22, 5.25)"),
    "mirror_alpha": Field("float", 0.5, "virtual lanes whose GGX α is at most this trace "
                          "one reflection ray into the mixed proxy instead of the specular "
                          "cone (arlight.realtime.mirror_rays; issue #33: a virtual mirror's "
                          "cone read the floor from V_ρ, reduced lights only, and hid its "
                          "photograph — held-out world-1000009's mirror cube black below); "
                          "0: cones everywhere, as Franke. 0.5 chosen on training worlds "
                          "(14 with glossy materials at 160 px: 0.2 +0.3…+5.1 dB on the 8 "
                          "with α ≤ 0.2, 0.5 also +0.2…+1.1 on 4 glossy ones up to α 0.39, "
                          "1.0 the same as 0.5, none lost)", "", min=0.0, max=1.0),
    "mirror_alpha_real": Field("float", 0.2, "the same for real specular lanes (a glossy "
                               "floor under the objects): a mirror hides its reflection where "
                               "the ray meets a virtual surface, a rough lane adds the change "
                               "along the ray and the lights' highlight the objects block "
                               "(tests/methods/test_dvct_mirror.py); 0.2 chosen on 20 training "
                               "worlds with real glossy surfaces at 160 px (benchmarks/"
                               "tune_mirror_real.py: +0.01…+13.3 dB on 9, −2.0 on world-276 "
                               "and −0.2 on world-163, 0.1 and 0.15 fewer gains; 0.25 lost "
                               "1.9 dB on world-14, α 0.22, its blur lost to one ray)",
                               "", min=0.0, max=1.0),
    "shells": Field("float", SHELLS, "coverage scale of a level-l block, α_l = min(1, "
                    "max(1, shells·2^l)·mean α): 1 exact for one sheet, 0.5 for closed "
                    "surfaces (ours; chosen on training worlds, issue #30)", "", min=0.0,
                    max=1.0, exclusive_min=True),
    "level_bias": Field("float", LEVEL_BIAS, "cones sample mip levels this much finer than "
                        "log2(diameter / cell) (ours; [CNS+11], Franke: 0; chosen on training "
                        "worlds, issue #30)", "levels", min=0.0, max=4.0),
    # fixed_lattice as fragments.LATTICE_OPTIONS, but off for dvct: on 6 training worlds the
    # lattice cost 1.4 dB of median changed_psnr
    # (world-0 −2.9 dB; lattices of 4 and 8 positions per edge alike), dlpv's was neutral
    "fixed_lattice": Field("bool", False, "place the volume on a fixed world lattice (moves "
                           "in steps of a quarter of its edge, keeps the real voxels and "
                           "RSMs while it stays; issue #32); off: centred on the object as "
                           "Franke (chosen on training worlds, docs/methods/dvct.md)"),
    "volume_extent": Field("choice", "frame", "the extent the volume's edge is "
                           "volume_scale × (issue #32): `frame`, with one virtual object the "
                           "largest edge of its bounding box in its own frame (a turn keeps "
                           "the cells; with several objects as `box`: on 8 training worlds "
                           "the union of their own-frame cubes made cells up to 30 % larger "
                           "and cost two of them 1.3–1.4 dB); `box`, the largest edge of the "
                           "world-axis bounding box as Franke (changes as the object turns)",
                           choices=("frame", "box")),
    **REDUCTION_OPTIONS,
    **gbuffer_options(AA_GBUFFER_SPP),
}


COVERAGE_BLOCKS = 8
"""Directional RSMs cover a sphere whose centre is the volume's centre snapped to a lattice
of ``edge / COVERAGE_BLOCKS`` and whose radius covers the volume from any snapped centre,
``√3/2 · edge · (1 + 1/COVERAGE_BLOCKS)``: a volume that moves less than an eighth of its
edge keeps the proxy's directional maps (issue #32; their texels 0.79× as dense)."""


def _check(opts: Options) -> None:
    n = int(opts.volume_size)
    if n & (n - 1):
        raise InputError(f"volume_size must be a power of two (mip chain), got {n}",
                         field="options.volume_size")


def drag_options(options: Options, factor: int) -> dict[str, int]:
    """Options of a studio frame at 1/``factor`` of the size while dragging (issue #32): the
    RSM side and the volume's cells per edge divided by ``factor`` (at least 64 texels, 32
    cells; the volume stays a power of two): RSMs, voxelisation, injection and the mip
    filter do not shrink with the image otherwise; one G-buffer sample per pixel
    (:func:`~arlight.methods.fragments.drag_gbuffer_spp`, as dir and dlpv: the upsampling
    filters wider than the AA samples would); the surround along the nine cones' axes
    (``surround_rays`` 0) and no far bounce: 16 rays per lane and shadow rays per hit
    doubled an 80×60 drag frame (the frame at rest has them)."""
    return {"rsm_size": max(64, options.rsm_size // factor),
            "volume_size": max(32, options.volume_size // factor),
            "surround_rays": 0, "far_bounce": False,
            **drag_gbuffer_spp(options, factor)}


SPEC = MethodSpec(
    name="dvct",
    description="Delta Voxel Cone Tracing (Franke 2014): voxelised scene, delta volume, "
                "shadow, diffuse and specular cones; real time on a GPU.",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, materials=frozenset(
        {"diffuse", "phong", "mirror", "roughconductor"}), lights=REDUCIBLE_LIGHTS),
    check=_check,
    drag_options=drag_options,
    frame_options=GBUFFER_FRAME_OPTIONS,
)

LUM = np.array([0.2126, 0.7152, 0.0722])


# --------------------------------------------------------------------------------------------
# Per-world data
# --------------------------------------------------------------------------------------------

@dataclass
class Materials:
    """Per-shape specular parameters (index = shape index in the world), Dr.Jit arrays:
    ``spec`` specular reflectance / F0 (RGB), ``rough`` GGX α (0 for mirrors), ``hide`` the
    specular share of the pixel's radiance (occlusion weighting), all 0 on diffuse shapes."""

    spec: mi.Color3f
    rough: mi.Float
    hide: mi.Float

    @staticmethod
    def of(world: World) -> Materials:
        spec, rough, hide = [], [], []
        for s in world.shapes:
            p, t = s.material.params, s.material.type
            ks, a, h = np.zeros(3), 0.0, 0.0
            if t == "mirror":
                ks, h = np.broadcast_to(np.asarray(p["reflectance"], float), (3,)), 1.0
            elif t == "roughconductor":
                ks, a, h = np.broadcast_to(np.asarray(p["reflectance"], float), (3,)), float(
                    p["alpha"]), 1.0
            elif t == "phong":
                ks = np.broadcast_to(np.asarray(p["ks"], float), (3,))
                kd = np.broadcast_to(np.asarray(p["kd"], float), (3,))
                a = math.sqrt(2.0 / (float(p["exponent"]) + 2.0))  # Walter et al. 2007
                h = float(ks @ LUM) / max(float(ks @ LUM + kd @ LUM), 1e-12)
            spec.append(ks)
            rough.append(a)
            hide.append(h)
        arr = np.asarray(spec, np.float32).reshape(-1, 3)
        return Materials(mi.Color3f(*(arr[:, c] for c in range(3))),
                         mi.Float(np.asarray(rough, np.float32)),
                         mi.Float(np.asarray(hide, np.float32)))

    def at(self, shape: mi.Int32, active: mi.Bool) -> tuple[mi.Color3f, mi.Float, mi.Float]:
        idx = mi.UInt32(dr.maximum(shape, 0))
        ok = active & (shape >= 0)
        return (dr.gather(mi.Color3f, self.spec, idx, ok), dr.gather(mi.Float, self.rough,
                                                                      idx, ok),
                dr.gather(mi.Float, self.hide, idx, ok))


ENV_SAMPLES = 64
"""GGX importance samples per texel of the prefiltered environment (as ``ibl``'s default
``samples``; :func:`~arlight.realtime.ibl_shading.prefilter_ggx`)."""


@dataclass
class DistantLight:
    """The distant light that a virtual object's specular cone meets when it leaves the
    volume (issue #33): ``env`` the world's environment (:func:`~arlight.realtime.
    ibl_shading.environment_map`, every ``envmap``/``sh``/``constant`` light) prefiltered per
    GGX roughness (:func:`~arlight.realtime.ibl_shading.prefilter_ggx`), ``dfg`` the
    split-sum table, ``tables`` the per-shape GGX ``α``, ``F0``, ``F90``
    (:func:`~arlight.realtime.ibl_shading.specular_tables`) and ``near`` the reduced lights
    that are *not* part of the environment (their specular stays direct: the environment
    already holds the directional lights extracted from it)."""

    env: MipEnvironment
    dfg: mi.Float
    tables: SpecularTables
    near: LightSet

    @staticmethod
    def of(world: World, lights: LightSet) -> DistantLight | None:
        """The distant light of ``world`` (None without an environment or without a glossy
        virtual shape)."""
        img = environment_map(world)
        tables = specular_tables(world)
        if img is None or not tables.glossy:
            return None
        return DistantLight(prefilter_ggx(img, ENV_SAMPLES), mi.Float(dfg_table().reshape(-1)),
                            tables, split_lights(world, lights)[1])


@dataclass
class DVCTData:
    """What ``prepare_world`` keeps: world, Mitsuba views, reduced lights, the volume grid
    (None without virtual objects), the real proxy's voxels, the virtual objects' triangles
    (re-voxelised every frame), per-shape materials, the light radii (m) of the shadow
    cones (directional lights: ``tan(γ/2)``), the real proxy's RSMs (cast once) and the
    window the proxy's voxels are cut from (:func:`proxy_voxels`)."""

    world: World
    views: SceneViews
    lights: LightSet
    grid: Grid | None
    real_voxels: Voxels | None
    virtual_triangles: np.ndarray | None
    materials: Materials
    light_size: list[float]
    real_maps: RealMaps | None = None
    real_window: LatticeVoxels | None = None
    distant: DistantLight | None = None
    mirror: MirrorLight | None = None
    """What the mirror rays' hits are shaded with (:func:`mirror_light`; None when
    ``mirror_alpha`` and ``mirror_alpha_real`` are both 0), built with the lights."""


def _light_sizes(world: World, lights: LightSet, options: Options) -> list[float]:
    """Per reduced light: the radius (m) of the disk its shadow cone opens onto (Eq. 5.20:
    "the cone aperture γ directly depends on the area of the light source") — an area light's
    ``area_grid²`` patches each as a disk of the patch's area, point and spot lights
    ``point_light_radius``; for directional lights ``tan(γ/2)``."""
    by_name = {(lt.name or f"light{i}"): lt for i, lt in enumerate(world.lights)}
    out = []
    for lt in lights.lights:
        if lt.kind == "directional":
            out.append(math.tan(math.radians(options.directional_aperture_deg) / 2.0))
        elif lt.kind == "cosine":
            src = by_name[lt.source].params
            m = np.asarray(src["to_world"], np.float64)
            area = float(np.linalg.norm(np.cross(m[:3, 0] * src["size"][0],
                                                 m[:3, 1] * src["size"][1])))
            out.append(math.sqrt(area / math.pi) / options.area_grid)
        else:
            out.append(float(options.point_light_radius))
    return out


def place_volume(world: World, bounds: tuple[np.ndarray, np.ndarray], options: Options
                 ) -> Grid:
    """The volume around the virtual objects (world-axis bounding box ``bounds``, m): with
    ``fixed_lattice`` the world lattice of ``dlpv`` (:func:`~arlight.methods.fragments.
    volume_grid`); otherwise Franke's cube of edge ``volume_scale`` × the extent of
    ``volume_extent`` (``frame`` and one virtual object: the cell rounded to float32
    precision — the extent is invariant under rigid motion only up to float64 rounding,
    which the coarser rounding absorbs, so a turn keeps the cell bitwise; several objects:
    ``box``),
    centred on ``bounds``' centre snapped to the cell lattice: origin ``k · cell`` for an
    integer ``k``, so that every placement with that cell lies on one world lattice
    (:class:`~arlight.realtime.voxels.LatticeVoxels`). Depends on the posed world alone
    (preparing it places the same volume)."""
    if options.fixed_lattice:
        return volume_grid(bounds, options)
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    n = int(options.volume_size)
    shapes = world.virtual_shapes
    if options.volume_extent == "box" or len(shapes) != 1:
        cell = max(float(np.max(hi - lo)), 1e-6) * options.volume_scale / n
    else:
        extent = max(frame_box(shapes[0])[1], 1e-6)
        cell = float(np.float32(extent * options.volume_scale / n))
    k = np.round((lo + hi) / 2.0 / cell) - n // 2
    return Grid(origin=k * cell, cell=cell, n=n)


def directional_coverage(grid: Grid) -> tuple[np.ndarray, float]:
    """(centre, radius) of the sphere directional RSMs cover (:data:`COVERAGE_BLOCKS`), m:
    it holds the volume for every centre within half a lattice step of the snapped one."""
    step = grid.size / COVERAGE_BLOCKS
    centre = np.round(grid.centre / step) * step
    return centre, math.sqrt(3.0) / 2.0 * (grid.size + step)


def proxy_voxels(world: World, grid: Grid, options: Options,
                 window: LatticeVoxels | None = None) -> tuple[Voxels, LatticeVoxels]:
    """The real proxy's voxels on ``grid`` cut from ``window`` — or, when it does not hold
    the grid, from a new window voxelised around it (:meth:`LatticeVoxels.around`) — and
    the window used: bitwise the voxels of the grid wherever the window lies."""
    cut = None if window is None else window.cut(grid)
    if cut is None:
        window = LatticeVoxels.around(world.real_shapes, grid, options.directional_occupancy)
        cut = window.cut(grid)
    assert cut is not None and window is not None
    return cut, window


def prepare(world: World, options: Options) -> DVCTData:
    """Mitsuba views, reduced lights, volume placement, the real proxy's voxels and RSMs."""
    check_rsm_memory(options.rsm_size)
    check_memory(options.volume_size,
                 2 * (light_channels(options) - 3)
                 + (COVER_CHANNELS if options.directional_occupancy else 0))
    views = build_views(world)
    lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
    bounds = virtual_bounds(world, views.mixed) if world.has_virtual else None
    grid = real = tris = maps = window = None
    if bounds is not None:
        grid = place_volume(world, bounds, options)
        real, window = proxy_voxels(world, grid, options)
        tris = np.concatenate([shape_triangles(s) for s in world.virtual_shapes])
        maps = real_maps(views, lights, grid, options.rsm_size, bounds,
                         directional_coverage(grid))
    distant = DistantLight.of(world, lights)
    return DVCTData(world, views, lights, grid, real, tris, Materials.of(world),
                    _light_sizes(world, lights, options), maps, window, distant,
                    mirror_light(views, lights, world, distant, options))


def mirror_light(views: SceneViews, lights: LightSet, world: World,
                 distant: DistantLight | None, options: Options) -> MirrorLight | None:
    """:class:`~arlight.realtime.mirror_rays.MirrorLight` of the world and its reduced
    lights, once per world and lighting (its tables, prefiltered environment and per-shape
    roles do not change as objects move); None when no lane traces a mirror ray."""
    if max(float(options.mirror_alpha), float(options.mirror_alpha_real)) <= 0.0:
        return None
    return MirrorLight.of(views, lights, world, distant)


def pose(data: DVCTData, world: World, transforms: dict[str, np.ndarray], options: Options
         ) -> DVCTData | None:
    """``data`` (prepared for ``world`` in any pose) moved in place to
    ``world.posed(transforms)`` (issue #32). What a pose recomputes: the shapes move in the
    Mitsuba views (their BVH is updated); the volume is placed again (:func:`place_volume`:
    with ``volume_extent`` ``frame`` a turn keeps the cell size, a move shifts the origin by
    whole cells); the real proxy's voxels are cut from the window voxelised at preparation
    (voxelised again only when the volume leaves it or its cell changes); the proxy's
    ``R_µ`` are kept — a point, spot or area light's rays do not depend on the volume, a
    directional light's cover :func:`directional_coverage`, which moves only every eighth
    of the volume's edge — and only the virtual objects' triangles are transformed. The
    rest is per frame anyway: the RSM pair casts only the rays that cross the objects' box
    into the mixed view (:func:`~arlight.realtime.rsm.render_rsm_pair_reusing`), the
    virtual objects are voxelised and every volume injected and filtered. Bitwise the data
    :func:`prepare` makes of the posed world; None (nothing changed) when a real shape
    moves."""
    posed = place_views(data.views, world, transforms)
    if posed is None:
        return None
    if data.grid is None or data.real_maps is None:
        return replace(data, world=posed)
    bounds = virtual_bounds(posed, data.views.mixed)
    grid = place_volume(posed, bounds, options)
    if same_grid(data.grid, grid):
        real, window = data.real_voxels, data.real_window
    else:
        real, window = proxy_voxels(posed, grid, options, data.real_window)
    tris = np.concatenate([shape_triangles(s) for s in posed.virtual_shapes])
    return replace(data, world=posed, grid=grid, real_voxels=real, real_window=window,
                   virtual_triangles=tris,
                   real_maps=moved_maps(data.real_maps, data.views, grid, bounds,
                                        directional_coverage(grid)))


# --------------------------------------------------------------------------------------------
# Volumes of one frame
# --------------------------------------------------------------------------------------------

@dataclass
class Volumes:
    """The filtered volumes of one frame: ``alpha`` (V_η: α_all, α_real), ``normal`` (V_η
    mean normals; filtered only with the ``back_faces`` option), ``delta`` (V_Δ) and ``rho``
    (V_ρ) intensities (W/sr), and counters."""

    alpha: MipVolume
    normal: MipVolume | None
    delta: MipVolume
    rho: MipVolume
    vpls_delta: int
    voxels: int
    cover: MipVolume | None = None


VPLGroups = list[tuple[list[mi.Float], mi.UInt32, mi.Bool]]


def _vpls(grid: Grid, position: mi.Point3f, normal: mi.Vector3f, flux: mi.Color3f,
          active: mi.Bool, sign: float, channels: int) -> tuple[VPLGroups, int]:
    """VPL intensities ``sign · Φ/π`` (Eq. 5.17) as groups ``(RGB values, slot, active)``
    for :func:`_packed_level`, each at the cell of its position moved half a cell along its
    normal, and the number of VPLs injected.

    A 3-channel level (isotropic) receives the peak intensity ``Φ/π``; an anisotropic one
    (:data:`~arlight.realtime.voxels.ANISO_CHANNELS`, 6 directions × RGB) the Lambertian
    intensity towards each axis direction ``e``, ``Φ/π · max(0, <n, e>)`` (a cone reads
    ``Σ_a |ω_a| c_slot(a)``, exactly ``Φ/π · max(0, <n, ω>)`` for axis-aligned ``n``)."""
    # opaque: the cell changes as the objects turn (a literal compiled a kernel per frame)
    idx, inside = cell_index(grid, position + normal * opaque(0.5 * grid.cell))
    act = active & inside
    val = flux * (sign / math.pi)
    if channels == 3:
        parts = [(mi.UInt32(0), mi.Float(1.0), 1)]
    else:  # emission towards n: the slots a cone travelling along −n reads
        parts = [(slot, w, 6) for slot, w in aniso_lookup(-normal)]
    groups = [([val[0] * w, val[1] * w, val[2] * w], idx * stride + slot, act)
              for slot, w, stride in parts]
    return groups, int(dr.count(act)[0]) if dr.width(act) else 0


def _packed_level(grid: Grid, groups: VPLGroups, channels: int) -> mi.Float:
    """The packed finest level (``n³ · channels``, RGB innermost) holding the sums of the
    VPL ``groups`` per cell and slot: order-independent (fixed-point) sums over every group,
    converted to float once per volume."""
    slots = grid.n ** 3 * (channels // 3)
    buf = dr.zeros(mi.Float, slots * 3)
    if not groups:
        return buf
    sums = scatter_sums_exact(groups, slots)
    for c in range(3):
        dr.scatter(buf, sums[c], dr.arange(mi.UInt32, slots) * 3 + c)
    return buf


def inject_split(grid: Grid, pairs: list[RSMPair], channels: int = 3, lost: bool = True
                 ) -> tuple[mi.Float, mi.Float, int]:
    """Split injection (thesis §5.4.1, Eq. 5.17): packed finest levels of ``V_Δ`` (only the
    texels whose mixed hit is virtual: ``+R_ρ`` there, ``−R_µ`` at what the real scene shows
    there) and ``V_ρ`` (every ``R_ρ`` texel); ``channels`` 3 (isotropic) or
    :data:`~arlight.realtime.voxels.ANISO_CHANNELS`. ``lost`` False (option
    ``lost_bounce`` off): without the ``−R_µ`` VPLs, ``V_Δ`` holds the virtual objects'
    own bounce alone."""
    delta, rho = [], []
    count = 0
    for pair in pairs:
        r = pair.rho
        rho += _vpls(grid, r.position, r.normal, r.flux_out, r.valid, 1.0, channels)[0]
        if dr.width(pair.changed) == 0:
            continue
        rc, mc = pair.rho_changed(), pair.mu_changed
        got, n = _vpls(grid, rc.position, rc.normal, rc.flux_out, rc.valid, 1.0, channels)
        delta += got
        count += n
        if lost:
            delta += _vpls(grid, mc.position, mc.normal, mc.flux_out, mc.valid, -1.0,
                           channels)[0]
    out = _packed_level(grid, delta, channels), _packed_level(grid, rho, channels)
    dr.eval(out)
    return *out, count


def inject_regular(grid: Grid, pairs: list[RSMPair], which: int, channels: int = 3
                   ) -> mi.Float:
    """Packed finest level of a regular volume: every ``R_ρ`` (``which=0``) or ``R_µ``
    (``which=1``) texel — ``V_ρ`` and ``V_µ`` of Eq. 5.26 (``channels`` as
    :func:`inject_split`)."""
    groups = []
    for pair in pairs:
        r = pair.rho if which == 0 else pair.mu()
        groups += _vpls(grid, r.position, r.normal, r.flux_out, r.valid, 1.0, channels)[0]
    buf = _packed_level(grid, groups, channels)
    dr.eval(buf)
    return buf


def light_channels(options: Options) -> int:
    """Channels per cell of ``V_Δ``, ``V_ρ`` (and ``V_µ``): 18 with ``anisotropic``, else 3."""
    return ANISO_CHANNELS if options.anisotropic else 3


def build_volumes(data: DVCTData, options: Options, timer: StageTimer | None = None
                  ) -> Volumes | None:
    """RSMs, voxelisation, split injection and filtering of one frame (Table 5.6 rows)."""
    timer = timer or StageTimer()
    grid = data.grid
    if grid is None:
        return None
    with timer.stage("rsm"):
        pairs = rsm_pair(data)
    with timer.stage("voxelize"):
        virt = voxelize(data.virtual_triangles, grid,
                        with_cover=bool(options.directional_occupancy))
        both = data.real_voxels.union(virt)
        alpha0, normal0 = eta_level0(data.real_voxels, virt, both)
    ch = light_channels(options)
    with timer.stage("inject"):
        if pairs:
            d0, r0, count = inject_split(grid, pairs, ch, options.lost_bounce)
        else:
            d0 = r0 = dr.zeros(mi.Float, grid.n ** 3 * ch)
            count = 0
    with timer.stage("filter"):
        alpha = build_mips(alpha0, grid, 2)
        normal = build_mips(normal0, grid, 3) if options.back_faces else None
        delta = build_mips(d0, grid, ch)
        rho = build_mips(r0, grid, ch)
        cover = build_mips(cover_level0(data.real_voxels, virt, both), grid,
                           COVER_CHANNELS) if options.directional_occupancy else None
    return Volumes(alpha, normal, delta, rho, count, both.occupied, cover)


# --------------------------------------------------------------------------------------------
# Cones
# --------------------------------------------------------------------------------------------

DELTA_VISIBILITY = 2
"""Which occlusion attenuates the light diffuse cones gather from ``V_Δ`` on real surfaces:
2, the virtual objects' only (``keep``): the receiving surface's false self-occlusion at
coarse levels would otherwise hide the bounce (:func:`~arlight.realtime.voxels.trace_cones`);
real walls between a virtual bounce and a real receiver are not counted (ours)."""

SHADOW_LIFT = 0.5
"""Shadow cones start this many cells off the surface along its normal and
:data:`SHADOW_START` cells along the cone. The per-sample transmittance cancels the real
receiver's own occlusion, so they can start close: lifted by 1.5 cells (and 0.5 along) they
darkened a band along the objects' bases (bunny-box 33.40 → 33.77 dB approx., point-light
shadow IoU 0.84/0.93 → 0.86/0.95 at 64³/256³; red-paper −0.05 dB)."""
SHADOW_START = 1.5

DIFFUSE_START = 2.0
"""Diffuse cones start this many cells off the surface along its normal."""

RING_POLAR = math.radians(60.0)
"""Polar angle of the 8 outer diffuse cones (the 9th is along the normal)."""


def diffuse_cone_set(aperture_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The 9 diffuse cones in the normal's local frame (z = normal): unit directions
    ``(9, 3)``, weights ``(9,)`` with ``Σ w = π`` (a uniform radiance ``L`` gathers
    ``E = πL``: the centre cone takes the cosine-weighted cap within half the aperture,
    ``π sin²(σ/2)``, the 8 ring cones share the rest), and ``tan(σ/2)``."""
    half = math.radians(aperture_deg) / 2.0
    cap = math.pi * math.sin(min(half, math.pi / 2)) ** 2
    dirs = [[0.0, 0.0, 1.0]]
    for k in range(8):
        phi = 2.0 * math.pi * k / 8
        dirs.append([math.sin(RING_POLAR) * math.cos(phi), math.sin(RING_POLAR) * math.sin(phi),
                     math.cos(RING_POLAR)])
    w = np.array([cap] + [(math.pi - cap) / 8.0] * 8)
    return np.array(dirs), w, math.tan(half)


def surround_set(count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` cosine-distributed unit directions in the normal's local frame (z =
    normal), ``(count, 3)``, and their weights ``(count,)``, each ``π / count`` (``Σ w =
    π``, as :func:`diffuse_cone_set`): Vogel's spiral on the unit disk (radius
    ``√((i + ½)/count)``, angle ``i`` × the golden angle ``π(3 − √5)``) lifted onto the
    hemisphere (Malley's method: a uniform disk point projects to a cosine-weighted
    direction), so ``Σ_i w_i f(d_i)`` is a quasi-Monte Carlo estimate of ``∫ f(ω) <n, ω>+
    dω``. :func:`real_surround`'s rays (issue #33): the nine cone axes, one ray each, turned
    a smooth surface's sky visibility into steps (a quarter of it flips with the central
    ray where the normal crosses the horizon: a band across a bevelled cube's face)."""
    i = np.arange(count) + 0.5
    r = np.sqrt(i / count)
    phi = np.arange(count) * math.pi * (3.0 - math.sqrt(5.0))
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - r * r, 0.0))],
                    1)
    return dirs, np.full(count, math.pi / count)


@dataclass
class Lanes:
    """G-buffer lanes that cones start from: position, normal, view direction (to the
    camera), role and shape."""

    position: mi.Point3f
    normal: mi.Vector3f
    to_camera: mi.Vector3f
    role: mi.Int32
    shape: mi.Int32

    def subset(self, idx: mi.UInt32) -> Lanes:
        return Lanes(*(dr.gather(type(v), v, idx) for v in (self.position, self.normal,
                                                              self.to_camera, self.role,
                                                              self.shape)))

    @property
    def width(self) -> int:
        return dr.width(self.role)


def diffuse_cones(vols: ConeVolumes, lanes: Lanes, aperture_deg: float,
                  alpha_for_light: int = 0, shells: float = SHELLS,
                  level_bias: float = LEVEL_BIAS) -> tuple[mi.Color3f, mi.Float, mi.Float]:
    """Nine diffuse cones per lane (Eq. 5.21 / 5.24): ``(Σ w_k C_k`` — irradiance, W/m² —
    ``, Σ w_k a_all,k / π, Σ w_k (1 − k)_k / π)``, the last two cosine-weighted
    occlusions in [0, 1]. Cones start two cells off the surface along the normal and sample
    the nearest mip level only (wide cones; half the gathers of quadrilinear sampling).
    ``shells``, ``level_bias``: see :func:`~arlight.realtime.voxels.trace_cones`."""
    dirs, w, tan_h = diffuse_cone_set(aperture_deg)
    n = lanes.width
    k = len(w)
    lane = dr.arange(mi.UInt32, n * k)
    src = lane // k
    cone = lane % k
    p = dr.gather(mi.Point3f, lanes.position, src)
    nrm = dr.gather(mi.Vector3f, lanes.normal, src)
    frame = mi.Frame3f(nrm)
    local = dr.gather(mi.Vector3f, mi.Vector3f(*(aligned(dirs[:, c], np.float32)
                                                 for c in range(3))), cone)
    d = frame.to_world(local)
    wt = dr.gather(mi.Float, mi.Float(aligned(w, np.float32)), cone)
    s0 = vols.alpha.grid.cell
    # opaque: the cell changes as the objects turn (a literal, a new kernel per frame)
    res = trace_cones(vols, p + nrm * opaque(DIFFUSE_START * s0), d, tan_h, dr.inf,
                      mi.Bool(True),
                      t_start=0.5 * s0, alpha_for_light=alpha_for_light,
                      quadrilinear=False, level_bias=level_bias, shells=shells)
    e = dr.block_sum(res.radiance * wt, k)
    ao = dr.block_sum(res.a_all * wt, k) * (1.0 / math.pi)
    added = dr.block_sum(res.added * wt, k) * (1.0 / math.pi)
    return e, ao, added


def reflect(v: mi.Vector3f, n: mi.Vector3f) -> mi.Vector3f:
    """Mirror direction of the unit direction ``v`` (towards the viewer) about ``n``."""
    return 2.0 * dr.dot(v, n) * n - v


def specular_cone(vols: ConeVolumes, lanes: Lanes, rough: mi.Float, min_aperture_deg: float,
                  active: mi.Bool, shells: float = SHELLS,
                  level_bias: float = LEVEL_BIAS) -> ConeResult:
    """One cone along the reflected view direction (Eq. 5.22 / 5.25), full aperture
    ``β = max(min_aperture, 2 atan(α))`` for GGX roughness ``α``."""
    tan_min = math.tan(math.radians(min_aperture_deg) / 2.0)
    d = reflect(lanes.to_camera, lanes.normal)
    s0 = vols.alpha.grid.cell
    # opaque: the cell changes as the objects turn (a literal, a new kernel per frame)
    return trace_cones(vols, lanes.position + lanes.normal * opaque(1.5 * s0), d,
                       dr.maximum(rough, tan_min), dr.inf, active, t_start=0.5 * s0,
                       level_bias=level_bias, shells=shells)


def light_direction(lt: ReducedLight, p: mi.Point3f) -> tuple[mi.Vector3f, mi.Float]:
    """Unit direction from ``p`` towards the light and its distance (inf: directional)."""
    if lt.kind == "directional":
        return -mi.Vector3f(*opaques(lt.axis)) + 0.0 * p.x, mi.Float(dr.inf)
    to = mi.Point3f(*opaques(lt.position)) - p
    dist = dr.norm(to)
    return to / dr.maximum(dist, 1e-12), dist


def shadow_cones(data: DVCTData, vols: ConeVolumes, lanes: Lanes, shells: float = SHELLS,
                 level_bias: float = LEVEL_BIAS) -> mi.Color3f:
    """Direct relighting (Eq. 5.20): ``−Σ_i (1 − k_i) E_i^µ`` (W/m²), one shadow cone per
    reduced light of half-angle ``atan(r_i / dist)`` (directional: the light's own), ``k_i``
    the transmittance the virtual objects leave along it
    (:func:`~arlight.realtime.voxels.trace_cones`) and ``E_i^µ`` light ``i``'s irradiance
    in the *real* proxy, with one shadow ray: the real-occluder question — where a real
    occluder already shadows the point, the photograph is dark and nothing is removed.
    The cones of all lights are one :func:`~arlight.realtime.voxels.trace_cones` call (lanes
    light-major; one loop kernel per frame however many lights, issue #32's fixed
    per-frame cost)."""
    lights = data.lights.lights
    if not lights:
        return mi.Color3f(0.0)
    s0 = vols.alpha.grid.cell
    n = lanes.width
    zero = dr.zeros(mi.Float, n)
    dirs, dists, tans, lits, irr = [], [], [], [], []
    for lt, size in zip(lights, data.light_size, strict=True):
        d, dist = light_direction(lt, lanes.position)
        r = opaque(size)  # a relit area light changes it: no literal in the kernel
        dists.append(zero + dist)
        tans.append(zero + r if lt.kind == "directional" else r / dr.maximum(dist, 1e-9))
        dirs.append(d)
        lits.append(dr.dot(d, lanes.normal) > 0.0)
        irr.append(direct_irradiance(data.views.real, LightSet([lt]), lanes.position,
                                     lanes.normal, mi.Bool(True), shadows=True))
    # widths as opaque scalars: the real lanes' count changes with every pose (as literals
    # it compiled the cone kernel again on every moving frame)
    width = dr.opaque(mi.UInt32, n)
    src = dr.arange(mi.UInt32, n * len(lights)) % width
    lifted = mi.Point3f(lanes.position + lanes.normal * opaque(SHADOW_LIFT * s0))
    start = dr.gather(mi.Point3f, lifted, src)
    lane = dr.arange(mi.UInt32, n)

    def light_major(parts: list) -> object:
        """The per-light 1D arrays one after another, scattered at opaque offsets
        (``dr.concat`` puts the widths into the kernel as literals)."""
        out = dr.zeros(type(parts[0]), n * len(parts))
        for i, part in enumerate(parts):
            dr.scatter(out, part, lane + width * i)
        return out

    direction = mi.Vector3f(*(light_major([d[c] for d in dirs]) for c in range(3)))
    res = trace_cones(vols, start, direction, light_major(tans), light_major(dists),
                      light_major(lits), t_start=SHADOW_START * s0, level_bias=level_bias,
                      shells=shells)
    added = res.added
    out = mi.Color3f(0.0)
    for i, e in enumerate(irr):
        out -= e * dr.gather(mi.Float, added, lane + width * i)
    return out


@dataclass
class ConeTerms:
    """Per cone lane. Real lanes: ``x`` delta irradiance (shadows + diffuse bounce + ambient
    occlusion, W/m²), ``y`` the specular cone's ``C_Δ`` (radiance), ``z`` its added
    occlusion. Virtual lanes: ``x`` the diffuse cones' irradiance from ``V_ρ``, ``y`` the
    specular cone's ``C_ρ``, ``z`` the ambient occlusion by the virtual objects (``1 − k``:
    a real surface that hides the sky from a virtual one reflects ambient light itself,
    which ``V_ρ`` — the RSMs' first bounce — does not hold; counting only the virtual
    occluders stands in for that reflection; ours)."""

    x: mi.Color3f
    y: mi.Color3f
    z: mi.Float
    t: mi.Float | None = None
    """Virtual lanes: the specular cone's transmittance ``1 − α_all`` where it leaves the
    volume, the share of the distant light it sees (1 without a specular cone)."""
    surround: tuple[mi.Color3f, mi.Float, mi.Color3f] | None = None
    """Virtual lanes: :func:`real_surround`'s ``(E_o, V, E_r)`` traced on the cones' lanes
    (None: :func:`shade` traces them per G-buffer sample)."""
    covered: mi.Bool | None = None
    """After :func:`upsample`: lanes with a same-role cone sample among their four (None:
    all); :func:`shade` traces the surround of the others itself (a thin virtual part
    between real cone samples)."""


def cone_volumes(vols: Volumes, options: Options) -> tuple[ConeVolumes, ConeVolumes]:
    """What the cones of real lanes (``V_Δ``, with ``V_ρ`` as the occluded bounce when
    ``occluded_bounce``) and of virtual lanes (``V_ρ``) read; both with the directional
    occupancy when built."""
    return (ConeVolumes(vols.alpha, vols.normal, vols.delta,
                        vols.rho if options.occluded_bounce else None, vols.cover),
            ConeVolumes(vols.alpha, vols.normal, vols.rho, None, vols.cover))


def diffuse_visibility(role: int, options: Options) -> int:
    """``alpha_for_light`` of the diffuse cones of lanes of ``role``
    (:func:`~arlight.realtime.voxels.trace_cones`): :data:`DELTA_VISIBILITY` on real lanes;
    on virtual lanes 0 (``α_all``), or 1 (``α_real``) without ``virtual_self_occlusion``."""
    if role == ROLE_REAL:
        return DELTA_VISIBILITY
    return 0 if options.virtual_self_occlusion else 1


def ambient_fill(data: DVCTData) -> mi.Color3f:
    """The radiance a virtual object shows where it blocks the SH ambient remainder,
    ``ρ_v L̄`` (W sr⁻¹ m⁻²; :func:`arlight.realtime.ambient.virtual_albedo` × the
    remainder's mean radiance ``L_00 Y_00``, Eq. 3 of :mod:`arlight.realtime.ambient`): on
    real lanes the blocked ambient is ``L_a − ρ_v L̄`` per occluded direction, on virtual
    lanes the self-occluded directions see ``ρ_v L̄``."""
    fill = virtual_albedo(data.world) * np.asarray(data.lights.ambient_sh, np.float64)[0] * Y00
    return mi.Color3f(*opaques(fill))


def real_fill(data: DVCTData, gb: GBuffer) -> mi.Color3f:
    """The ambient radiance of a real surface that hides the SH remainder from a virtual
    one, ``ρ_r L̄`` (W sr⁻¹ m⁻²): ``ρ_r`` the mean G-buffer albedo of the frame's real
    pixels (the proxy the camera sees), ``L̄ = L_00 Y_00`` the remainder's mean radiance —
    what ``V_ρ`` lacks (the RSMs hold the reduced lights only), the real counterpart of
    :func:`ambient_fill`."""
    real = gb.valid & ~gb.virtual
    count = dr.maximum(dr.sum(dr.select(real, 1.0, 0.0)), 1.0)
    alb = dr.select(real, gb.albedo, mi.Color3f(0.0))
    rho = mi.Color3f(*(dr.sum(alb[c]) / count for c in range(3)))
    mean = np.asarray(data.lights.ambient_sh, np.float64)[0] * Y00
    return rho * mi.Color3f(*opaques(mean))


def cone_terms(data: DVCTData, vols: Volumes, lanes: Lanes, options: Options,
               stats: dict | None = None) -> ConeTerms:
    """All cones of ``lanes`` (real lanes against ``V_Δ``, virtual against ``V_ρ``)."""
    n = lanes.width
    x, y, z = dr.zeros(mi.Color3f, n), dr.zeros(mi.Color3f, n), dr.zeros(mi.Float, n)
    t = dr.full(mi.Float, 1.0, n)
    cv_delta, cv_rho = cone_volumes(vols, options)
    count = 0
    knobs = {"shells": float(options.shells), "level_bias": float(options.level_bias)}
    for role, cv in ((ROLE_REAL, cv_delta), (ROLE_VIRTUAL, cv_rho)):
        idx = dr.compress(lanes.role == role)
        if dr.width(idx) == 0:
            continue
        sub = lanes.subset(idx)
        count += dr.width(idx)
        xs = dr.zeros(mi.Color3f, dr.width(idx))
        zs = dr.zeros(mi.Float, dr.width(idx))
        if options.diffuse_cones:
            e, ao, added = diffuse_cones(cv, sub, options.diffuse_aperture_deg,
                                         diffuse_visibility(role, options), **knobs)
            if role == ROLE_REAL:
                # the ambient the objects block, less their own reflection of it
                # (realtime.ambient's Eq. 3: blocked radiance L_a − ρ_v L̄)
                amb = dr.maximum(ambient_irradiance_dr(data.lights, sub.normal)
                                 * (1.0 / math.pi) - ambient_fill(data), 0.0)
                xs = e - amb * (math.pi * added)
            else:
                xs, zs = e, added
        if role == ROLE_REAL and data.lights.lights and options.direct == "cones":
            xs = xs + shadow_cones(data, ConeVolumes(vols.alpha), sub, **knobs)
        ys = dr.zeros(mi.Color3f, dr.width(idx))
        if options.specular_cones:
            spec, rough, _ = data.materials.at(sub.shape, mi.Bool(True))
            limit = float(options.mirror_alpha if role == ROLE_VIRTUAL
                          else options.mirror_alpha_real)
            # the lanes that trace a ray instead (shade, mirror_terms) skip the cone
            has = (dr.max(spec) > 0.0) & ~mirror_traced(spec, rough, limit)
            sidx = dr.compress(has)
            if dr.width(sidx):
                ss = sub.subset(sidx)
                res = specular_cone(replace(cv, occluded=None), ss,
                                    dr.gather(mi.Float, rough, sidx),
                                    options.specular_min_aperture_deg, mi.Bool(True), **knobs)
                dr.scatter(ys, res.radiance, sidx)
                if role == ROLE_REAL:
                    dr.scatter(zs, res.added, sidx)
                else:
                    dr.scatter(t, 1.0 - res.a_all, dr.gather(mi.UInt32, idx, sidx))
        dr.eval(xs, ys, zs)
        dr.scatter(x, xs, idx)
        dr.scatter(y, ys, idx)
        dr.scatter(z, zs, idx)
    dr.eval(x, y, z, t)
    if stats is not None:
        stats["cone_lanes"] = float(count)
    return ConeTerms(x, y, z, t)


def cone_error(data: DVCTData, vols: Volumes, lanes: Lanes, options: Options,
               pairs: list[RSMPair]) -> dict[str, np.ndarray]:
    """The cone-tracing error of thesis Eq. 5.27, ``E = C_ρ − (C_µ + C_Δ)``, of the nine
    diffuse cones (irradiance, W/m², ``(N, 3)`` per lane): ``C_ρ`` gathers ``V_ρ`` with
    ``α_all``, ``C_µ`` a regular ``V_µ`` (every ``R_µ`` texel) with ``α_real`` and ``C_Δ``
    ``V_Δ`` with ``α_all``. At the finest level ``V_ρ = V_µ + V_Δ`` (Eq. 5.26); the cones
    differ because ``V_µ`` is seen through the real scene's occlusion. Returns the three
    terms and ``E``."""
    grid = vols.alpha.grid
    ch = light_channels(options)
    mu = build_mips(inject_regular(grid, pairs, 1, ch), grid, ch)
    out = {}
    for name, light, which in (("rho", vols.rho, 0), ("mu", mu, 1), ("delta", vols.delta, 0)):
        e, _, _ = diffuse_cones(ConeVolumes(vols.alpha, vols.normal, light), lanes,
                                options.diffuse_aperture_deg, which, float(options.shells),
                                float(options.level_bias))
        out[name] = np.array(e, np.float64).T
    out["error"] = out["rho"] - (out["mu"] + out["delta"])
    return out


# --------------------------------------------------------------------------------------------
# Reduced resolution and edge-aware upsampling
# --------------------------------------------------------------------------------------------

def low_res_lanes(gb: GBuffer, k: int) -> mi.UInt32:
    """G-buffer lanes of the cone samples: pixel ``(k i + k//2, k j + k//2)`` (clamped) of
    every ``k × k`` block, row-major over the ``ceil(H/k) × ceil(W/k)`` low-res grid."""
    hl, wl = -(-gb.height // k), -(-gb.width // k)
    rows = np.minimum(np.arange(hl) * k + k // 2, gb.height - 1)
    cols = np.minimum(np.arange(wl) * k + k // 2, gb.width - 1)
    pix = (rows[:, None] * gb.width + cols[None, :]).ravel()
    return mi.UInt32(aligned(pix * gb.spp, np.uint32))


def upsample(gb: GBuffer, k: int, low: Lanes, terms: ConeTerms, cell: float) -> ConeTerms:
    """Edge-aware (joint bilateral) upsampling of low-res cone terms to every G-buffer lane:
    the 4 nearest low-res samples, bilinear weights × ``exp(−(<n, p_s − p>/s)²)`` (distance of
    the sample from the pixel's tangent plane in cells) × ``max(0, <n, n_s>)⁸`` × same role;
    where every geometric weight vanishes, the same-role bilinear mean (weight 10⁻³).
    ``x``, ``y``, ``z`` on every lane; ``t``, ``surround`` and ``covered``, which only
    virtual lanes read (:func:`shade`), on the virtual lanes alone (compacted: at 640×480
    with 4 G-buffer samples most lanes are real, and the surround's seven channels were
    half the gathers; elsewhere ``t`` 1, ``surround`` 0, ``covered`` False)."""
    args = (gb, k, low, cell)
    (x, y, z), _ = _bilateral(*args, gb.pixel, gb.position, gb.normal, gb.role,
                              [terms.x, terms.y, terms.z])
    rest = ([] if terms.t is None else [terms.t]) + list(terms.surround or ())
    t, surround, covered = terms.t, terms.surround, None
    if rest:
        n = dr.width(gb.role)
        outs = [dr.zeros(type(v), n) for v in rest]
        if terms.t is not None:
            outs[0] = dr.full(mi.Float, 1.0, n)
        hit = dr.zeros(mi.Bool, n)
        idx = dr.compress(gb.virtual)
        if dr.width(idx):
            got, any_w = _bilateral(*args, *(dr.gather(type(a), a, idx) for a in (
                gb.pixel, gb.position, gb.normal, gb.role)), rest)
            if terms.t is not None:  # no same-role sample: the whole distant light
                got[0] = dr.select(any_w, got[0], 1.0)
            for o, g in zip(outs, got, strict=True):
                dr.scatter(o, g, idx)
            dr.scatter(hit, any_w, idx)
        if terms.t is not None:
            t = outs.pop(0)
        if terms.surround is not None:
            surround, covered = tuple(outs), hit
    out = ConeTerms(x, y, z, t, surround, covered)
    dr.eval(out.x, out.y, out.z, out.t, *(out.surround or ()), out.covered)
    return out


def _bilateral(gb: GBuffer, k: int, low: Lanes, cell: float, pix: mi.UInt32,
               p: mi.Point3f, n: mi.Vector3f, role: mi.Int32, values: list
               ) -> tuple[list, mi.Bool]:
    """:func:`upsample`'s filter of the low-res ``values`` at lanes of G-buffer pixel
    ``pix`` (position ``p``, normal ``n``, ``role``): the normalised weighted sums and
    whether any weight was non-zero (a same-role sample among the four)."""
    hl, wl = -(-gb.height // k), -(-gb.width // k)
    row = mi.Float(pix // gb.width)
    col = mi.Float(pix % gb.width)
    fy = (row - float(k // 2)) * (1.0 / k)
    fx = (col - float(k // 2)) * (1.0 / k)
    y0 = dr.floor(fy)
    x0 = dr.floor(fx)
    ty, tx = fy - y0, fx - x0
    acc = [dr.zeros(type(v), dr.width(pix)) for v in values]
    acc_w = mi.Float(0.0)
    inv = opaque(1.0 / cell)  # the cell changes as the objects turn: one kernel for all
    for dy in (0, 1):
        for dx in (0, 1):
            yy = dr.clip(mi.Int32(y0) + dy, 0, hl - 1)
            xx = dr.clip(mi.Int32(x0) + dx, 0, wl - 1)
            bil = (ty if dy else 1.0 - ty) * (tx if dx else 1.0 - tx)
            i = mi.UInt32(yy * wl + xx)
            ps = dr.gather(mi.Point3f, low.position, i)
            ns = dr.gather(mi.Vector3f, low.normal, i)
            rs = dr.gather(mi.Int32, low.role, i)
            plane = dr.dot(n, ps - p) * inv
            cosn = dr.maximum(dr.dot(n, ns), 0.0)
            cos2 = cosn * cosn
            cos8 = cos2 * cos2 * cos2 * cos2
            w = bil * (dr.exp(-plane * plane) * cos8 + 1e-3)
            w = dr.select(rs == role, w, 0.0)
            acc = [a + dr.gather(type(v), v, i) * w for a, v in zip(acc, values, strict=True)]
            acc_w += w
    norm = dr.select(acc_w > 0.0, dr.rcp(dr.maximum(acc_w, 1e-30)), 0.0)
    return [a * norm for a in acc], acc_w > 0.0


# --------------------------------------------------------------------------------------------
# Shading
# --------------------------------------------------------------------------------------------

def ggx_specular(n: mi.Vector3f, wo: mi.Vector3f, wi: mi.Vector3f, f0: mi.Color3f,
                 alpha: mi.Float) -> mi.Color3f:
    """GGX microfacet BRDF ``D G F / (4 <n,wi> <n,wo>)`` (Walter et al. 2007 [WMLT07], thesis
    Eq. 4.11ff): ``D`` and Smith's separable masking ``G1`` from
    :mod:`arlight.realtime.ibl_shading` (:func:`~arlight.realtime.ibl_shading.ggx_d`,
    :func:`~arlight.realtime.ibl_shading.smith_g1`), Schlick Fresnel from ``f0`` (sr⁻¹)."""
    a = dr.maximum(alpha, 1e-3)
    h = dr.normalize(wi + wo)
    cos_h = dr.maximum(dr.dot(n, h), 0.0)
    cos_i = dr.maximum(dr.dot(n, wi), 1e-6)
    cos_o = dr.maximum(dr.dot(n, wo), 1e-6)
    d = ggx_d(a, cos_h)
    f = f0 + (1.0 - f0) * dr.power(1.0 - dr.maximum(dr.dot(wi, h), 0.0), 5.0)
    return f * (d * smith_g1(a, cos_i) * smith_g1(a, cos_o) / (4.0 * cos_i * cos_o))


def escape_radiance(data: DVCTData, gb: GBuffer, seen: Reprojector | None,
                    active: mi.Bool) -> mi.Color3f:
    """What a virtual object's specular cone sees where it leaves the volume (issue #33;
    the cone itself holds only ``V_ρ``, the RSMs' first bounce inside the volume), as
    specular radiance (W sr⁻¹ m⁻², the BRDF applied) on the ``active`` lanes. One ray along
    the mirror direction into the real proxy decides: a miss sees the distant light, the
    split-sum ``L̃(d, α)(F0 A + F90 B)`` of the prefiltered environment
    (:func:`~arlight.realtime.ibl_shading.specular_split_sum`, [CNS+11]'s environment
    lookup for the transmittance left at the end of a cone); a hit sees a real surface
    whose radiance the photograph holds where the camera sees it (``seen``'s frame at the
    hit's projection, as onepass reprojects, Kán §5.2), times ``F0`` as the cone's ``C_ρ``;
    where the camera does not see it (behind the camera, hidden), its diffuse radiance in
    the proxy, ``ρ/π (E_direct + E_amb)`` (the reduced lights with shadow rays, the SH
    remainder unoccluded). Zero without a distant light."""
    far = data.distant
    n_l = dr.width(gb.role)
    if far is None:
        return dr.zeros(mi.Color3f, n_l)
    idx = dr.compress(active)
    out = dr.zeros(mi.Color3f, n_l)
    if dr.width(idx) == 0:
        return out
    p = dr.gather(mi.Point3f, gb.position, idx)
    n = dr.gather(mi.Vector3f, gb.normal, idx)
    v = dr.gather(mi.Vector3f, gb.to_camera, idx)
    shape = mi.UInt32(dr.maximum(dr.gather(mi.Int32, gb.shape, idx), 0))
    tab = far.tables
    f0 = dr.gather(mi.Color3f, tab.f0, shape)
    ray = mi.Ray3f(p + n * 1e-4, reflect(v, n))
    si = data.views.real.scene.ray_intersect(ray)
    env = specular_split_sum(far.env, far.dfg, n, v, dr.gather(mi.Float, tab.alpha, shape),
                             f0, dr.gather(mi.Color3f, tab.f90, shape))
    hit = si.is_valid()
    nh = facing(mi.Vector3f(si.n), -ray.d)
    lit = surface_albedo(si, hit) * (1.0 / math.pi) * (
        direct_irradiance(data.views.real, data.lights, si.p, nh, hit)
        + dr.maximum(ambient_irradiance_dr(data.lights, nh), 0.0))
    val = dr.select(hit, lit * f0, env)
    if seen is not None:
        photo, ok = seen.lookup(si.p, si.is_valid())[:2]
        val = dr.select(ok, photo * f0, val)
    dr.scatter(out, val, idx)
    return out


def mirror_traced(spec: mi.Color3f, rough: mi.Float, limit: float | mi.Float) -> mi.Bool:
    """The specular lanes (``spec`` > 0) whose GGX ``rough`` is at most the option's
    ``limit`` (``mirror_alpha`` / ``mirror_alpha_real``; 0: none): they take their
    reflection from one traced ray (:func:`mirror_terms`) and skip the specular cone."""
    return (dr.max(spec) > 0.0) & (rough <= limit) & (limit > 0.0)


def mirror_terms(data: DVCTData, gb: GBuffer, seen: Reprojector | None, traced: mi.Bool,
                 delta: mi.Color3f, hidden: mi.Float, hide: mi.Float, rough: mi.Float
                 ) -> tuple[mi.Color3f, mi.Float, mi.Color3f]:
    """The ``traced`` lanes' reflection from one ray each into the mixed proxy
    (:func:`arlight.realtime.mirror_rays.mirror_rays`; option ``mirror_alpha``), given the
    real lanes' ``delta`` and ``hidden`` of everything else and their GGX ``rough``: returns
    ``(delta, hidden, specular radiance of the virtual lanes)``. A real perfect mirror
    (``rough`` 0) whose ray meets a virtual surface hides its reflected background (``hidden
    = h``: its photograph is the radiance along the ray) and gains that surface's reflected
    radiance; a rougher real lane keeps its photograph, which also holds light from
    directions the one ray does not test (a lamp's glossy highlight around the object's
    reflection), and gains the change along the ray, ``(F0 A + F90 B)(L_µ(r) − L_ρ(r))``;
    one whose ray meets a real surface the camera sees gains the change of that surface's
    direct light. A virtual lane shows all its ray brings (the photograph at a seen real hit
    plus that change)."""
    light = data.mirror or MirrorLight.of(data.views, data.lights, data.world, data.distant)
    box = virtual_bounds(data.world, data.views.mixed)
    real = gb.valid & ~gb.virtual & traced
    rad, change, role = mirror_rays(light, gb.position, gb.normal, gb.to_camera, gb.shape,
                                    traced, seen, real,
                                    None if box is None else bounding_ball(box))
    on_virtual = real & (role == ROLE_VIRTUAL) & (rough <= 0.0)
    delta = delta + dr.select(on_virtual, rad, dr.select(real, change, mi.Color3f(0.0)))
    hidden = dr.select(on_virtual, hide, hidden)
    return delta, hidden, dr.select(gb.virtual & traced, rad, mi.Color3f(0.0))


def remainder_radiance(lights: LightSet, d: mi.Vector3f) -> mi.Color3f:
    """The SH remainder's radiance towards unit directions ``d``, ``L_a(d) = Σ c_lm
    Y_lm(d)`` (W sr⁻¹ m⁻², ≥ 0): :func:`~arlight.realtime.shading.ambient_irradiance_dr` of
    the coefficients divided by the clamped cosine's band weights ``Â_l`` (Ramamoorthi &
    Hanrahan 2001: ``E_lm = Â_l L_lm``), so the one polynomial evaluates either."""
    sh = np.asarray(lights.ambient_sh, np.float64)
    bands = band_of_each_coeff(order_of(sh.shape[0]))
    a_hat = np.array([clamped_cosine_band(int(b)) for b in bands])
    return dr.maximum(ambient_irradiance_dr(LightSet([], sh / a_hat[:, None]), d), 0.0)


def surround_wanted(data: DVCTData, options: Options | None = None,
                    far_bounce: bool | None = None) -> bool:
    """Whether virtual lanes trace :func:`real_surround`: with an SH remainder, or with
    ``far_bounce`` (the option's, or the given value) and reduced lights."""
    far = bool(options.far_bounce) if far_bounce is None else bool(far_bounce)
    return bool(np.any(data.lights.ambient_sh)) or (far and bool(data.lights.lights))


def real_surround(data: DVCTData, gb: GBuffer, seen: Reprojector | None, aperture_deg: float,
                  active: mi.Bool, rays: int = 0, far_bounce: bool = True
                  ) -> tuple[mi.Color3f, mi.Float, mi.Color3f]:
    """The real proxy around the ``active`` (virtual) lanes: the SH remainder's visibility
    through it and the light of its surfaces beyond the volume, for the nine diffuse cone
    directions (:func:`diffuse_cone_set`, weights ``w_k``, ``Σ w_k = π``) with one ray each —
    or, with ``rays`` > 0 (option ``surround_rays``), that many cosine-distributed rays
    (:func:`surround_set`, each ``π / rays``) split over a pixel's ``gb.spp`` G-buffer
    samples (sample ``s`` casts rays ``s, s + spp, …``, each weighted ``π`` / its own count:
    the pixel's samples cast the set once together, as the shadow rays, f74ec32) — the
    volume's cones see only the real geometry inside it (issue #33: a sphere in a room lit
    through an opening was lit as if the sky were open). Returns ``(E_o, V, E_r)``: ``V = Σ_k
    w_k miss_k / π`` the cosine-weighted share of open sky, ``E_o = Σ_k w_k miss_k L_a(d_k)``
    (W/m²) the remainder through it (:func:`remainder_radiance`: the sky the real proxy leaves
    is not the hemisphere's mean), and ``E_r = Σ_k w_k hit_k L_k`` (W/m²) the irradiance from
    the real surfaces hit instead. ``L_k``: beyond the volume the photograph at the hit's
    projection (all of its light: no cone reached it); beyond the volume where the camera
    does not see it, with ``far_bounce``, the hit's diffuse radiance ``ρ/π E_direct +
    ρ_r L̄`` (the reduced lights through shadow rays in the *mixed* scene, the objects'
    shadows on it included; issue #33: a virtual object in a room lit by a small lamp got
    none of the walls' bounce, the volume being twice the object), else (and inside the
    volume, where ``V_ρ`` holds its reduced lights' first bounce) its ambient part ``ρ_r L̄``
    (:func:`real_fill`). Zero on other lanes."""
    return surround_at(data, Lanes(gb.position, gb.normal, gb.to_camera, gb.role, gb.shape),
                       real_fill(data, gb), seen, aperture_deg, active, rays, far_bounce,
                       int(gb.spp))


def surround_at(data: DVCTData, lanes: Lanes, fill: mi.Color3f, seen: Reprojector | None,
                aperture_deg: float, active: mi.Bool, rays: int, far_bounce: bool,
                spp: int = 1) -> tuple[mi.Color3f, mi.Float, mi.Color3f]:
    """:func:`real_surround` on any ``lanes`` (``spp`` consecutive lanes are one pixel's
    samples, which split the ``rays``; ``fill`` the real surfaces' ``ρ_r L̄``): the cones'
    reduced-resolution lanes use it with ``spp = 1`` (every lane casts every ray) before
    the edge-aware upsampling (:func:`upsample`)."""
    # symbolic calls even where the studio's drag frames evaluate them (issue #32): the
    # rays' shape and BSDF calls, evaluated per ray, launched kernels per instance and ray
    # (an 80×60 drag frame 2–4 s instead of 0.15)
    with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, True):
        return _surround_at(data, lanes, fill, seen, aperture_deg, active, rays, far_bounce,
                            spp)


def _surround_at(data: DVCTData, lanes: Lanes, fill: mi.Color3f, reproj: Reprojector | None,
                 aperture_deg: float, active: mi.Bool, rays: int, far_bounce: bool,
                 spp: int) -> tuple[mi.Color3f, mi.Float, mi.Color3f]:
    n_l = lanes.width
    e_o, vis, e_r = dr.zeros(mi.Color3f, n_l), dr.zeros(mi.Float, n_l), dr.zeros(mi.Color3f,
                                                                                  n_l)
    idx = dr.compress(active)
    if dr.width(idx) == 0:
        return e_o, vis, e_r
    p = dr.gather(mi.Point3f, lanes.position, idx)
    frame = mi.Frame3f(dr.gather(mi.Vector3f, lanes.normal, idx))
    m = dr.width(idx)
    if rays > 0:  # sample s of the pixel casts rays s, s + spp, … (π / its count each)
        spp = max(1, min(int(spp), rays))
        table, weights = surround_set(rays)
        first = idx % spp
        scale = mi.Float((rays - first + spp - 1) // spp) * (1.0 / rays)  # its share
    else:  # the nine cone axes, every lane casts all
        table, weights = diffuse_cone_set(aperture_deg)[:2]
        spp, first, scale = 1, dr.zeros(mi.UInt32, m), mi.Float(1.0)
    count = len(table)
    tab = mi.Vector3f(*(mi.Float(aligned(table[:, c], np.float32)) for c in range(3)))
    wtab = mi.Float(aligned(weights, np.float32))
    grid = data.grid  # the box's corners opaque: it moves with the objects (issue #32)
    lo, hi = (opaques(grid.lo()), opaques(grid.hi())) if grid is not None else (None, None)

    def body(j: mi.UInt32, o_c: mi.Color3f, v_c: mi.Float, e_c: mi.Color3f):
        pick = first + j * spp
        on = pick < count
        pick = dr.minimum(pick, count - 1)
        d = frame.to_world(dr.gather(mi.Vector3f, tab, pick))
        wk = dr.select(on, dr.gather(mi.Float, wtab, pick) / scale, 0.0)
        si = data.views.real.scene.ray_intersect(mi.Ray3f(p + frame.n * 1e-4, d), on)
        hit = on & si.is_valid()
        radiance = mi.Color3f(fill)
        outside = mi.Bool(True) if lo is None else ~(
            (si.p.x > lo[0]) & (si.p.y > lo[1]) & (si.p.z > lo[2])
            & (si.p.x < hi[0]) & (si.p.y < hi[1]) & (si.p.z < hi[2]))
        far = hit & outside
        ok = mi.Bool(False)
        if reproj is not None:
            seen, ok = reproj.lookup(si.p, far)[:2]
            radiance = dr.select(ok, seen, radiance)
        if far_bounce and data.lights.lights:
            unseen = far & ~ok
            nh = facing(mi.Vector3f(si.n), -d)
            lit = direct_irradiance(data.views.mixed, data.lights, si.p, nh, unseen)
            radiance = dr.select(unseen, radiance + surface_albedo(si, unseen) * (
                1.0 / math.pi) * lit, radiance)
        v_c += dr.select(hit | ~on, 0.0, wk * (1.0 / math.pi))
        o_c += dr.select(hit | ~on, mi.Color3f(0.0), remainder_radiance(data.lights, d) * wk)
        e_c += dr.select(hit, radiance * wk, mi.Color3f(0.0))
        return j + 1, o_c, v_c, e_c

    # one symbolic loop over the rays: unrolled, a 16-ray set traced ~10⁴ operations into
    # one kernel every frame (recording them cost ~0.15 s per 640×480 frame, more than the
    # rays themselves)
    _, o_c, v_c, e_c = dr.while_loop(
        state=(dr.zeros(mi.UInt32, m), dr.zeros(mi.Color3f, m), dr.zeros(mi.Float, m),
               dr.zeros(mi.Color3f, m)),
        cond=lambda j, *_: j < -(-count // spp), body=body, label="surround_rays")
    for dst, src in ((e_o, o_c), (vis, v_c), (e_r, e_c)):
        dr.scatter(dst, src, idx)
    return e_o, vis, e_r


def shade(data: DVCTData, gb: GBuffer, terms: ConeTerms | None,
          frame: np.ndarray | None = None, seen: Reprojector | None = None,
          aperture_deg: float = 60.0, shadow_rays: int | None = None,
          surround_rays: int = 0, far_bounce: bool = False,
          mirror_alpha: tuple[float, float] = (0.0, 0.0)
          ) -> tuple[mi.Color3f, mi.Color3f, mi.Float]:
    """Per lane ``(mixed radiance on virtual lanes, delta radiance on real lanes, hidden
    fraction h·a of the background on real lanes)`` (§5.4.4). With the photograph ``frame``
    (option ``photo_albedo``) real lanes use the albedo read from it
    (:func:`arlight.realtime.photo_albedo.photo_albedo`) instead of the proxy's.

    ``shadow_rays`` (option ``direct = rays``): the real lanes' direct change ``ΔE_d = Σ_i
    E⊥_i <n, ω_i>+ (V_ρ,i − V_µ,i)`` (W/m², ``≤ 0``) is traced per G-buffer sample, that
    many shadow rays over an extended light (:func:`~arlight.realtime.shading.
    direct_terms_gbuffer`, the mixed scene's rays only where they can meet the objects),
    and added to the cones' ``ΔE`` (``terms.x`` then holds no shadow cones); the same rays
    give ``E_r``'s direct part for ``ρ̂`` (the real scene's visibility, soft over an
    extended light; no rays of its own). None (``direct = cones``): ``terms.x`` holds
    Eq. 5.20's shadow cones, and ``E_r`` traces one ray per light.

    ``mirror_alpha``: the options ``mirror_alpha`` and ``mirror_alpha_real``; virtual and
    real specular lanes of GGX ``α`` at most their limit (> 0) take their reflection from one
    traced ray instead of the specular cone (:func:`mirror_terms`)."""
    virt = gb.virtual
    real = gb.valid & ~virt
    n_l = dr.width(gb.role)
    if terms is None:
        z = dr.zeros(mi.Color3f, n_l)
        return z, z, dr.zeros(mi.Float, n_l)
    spec, rough, hide = data.materials.at(gb.shape, gb.valid)
    # real pixels: ρ/π ΔE + k_s C_Δ,spec, and −h a_spec B (applied by the caller)
    e_delta = terms.x
    direct = None
    if shadow_rays is not None:
        # light by light, the mixed scene's rays only on the lanes whose rays can meet the
        # objects (exact); the same rays give E_r's direct part (the real scene's soft
        # visibility) there, and where only the cones change the pixel one real-scene ray
        # per light (the central ray E_r traced before: soft there, 2 rays per light and
        # sample, cost dvct's shade stage ~0.3 s at 640×480 on a room with six lights)
        cones = real & (dr.max(dr.abs(terms.x)) > 0.0) if frame is not None \
            else mi.Bool(False)
        shared = direct_terms_gbuffer(data.views, data.lights, gb, real, shadow_rays,
                                      data.world, cones, far_samples=1)
        e_delta = e_delta + shared.change
        direct = shared.real
    rho = gb.albedo
    if frame is not None:
        changed = real & (dr.max(dr.abs(e_delta)) > 0.0)
        rho = photo_albedo(data.views.real, data.lights, frame, gb.pixel, gb.position,
                           gb.normal, gb.albedo, changed, direct=direct)
    traced = mi.Bool(False)
    if max(mirror_alpha) > 0:  # the virtual lanes' limit, the real lanes'
        traced = gb.valid & mirror_traced(spec, rough,
                                          dr.select(virt, mirror_alpha[0], mirror_alpha[1]))
    cone = dr.select(traced, mi.Color3f(0.0), spec * terms.y)
    delta = rho * (1.0 / math.pi) * e_delta + cone
    delta = dr.select(real, delta, mi.Color3f(0.0))
    hidden = dr.select(real & ~traced, hide * terms.z, 0.0)
    if max(mirror_alpha) > 0:
        delta, hidden, ray_mixed = mirror_terms(data, gb, seen, traced, delta, hidden, hide,
                                                rough)
    # virtual pixels (Eq. 5.23–5.25)
    e_dir = direct_irradiance_compact(data.views.mixed, data.lights, gb.position, gb.normal,
                                      virt)
    e_amb = ambient_irradiance_dr(data.lights, gb.normal)
    if terms.surround is not None or surround_wanted(data, far_bounce=far_bounce):
        # Σ_k w_k (open sky, virtual object, real surface)
        # the virtual objects' occlusion z taken from the open directions (a share z / V)
        todo = virt if terms.surround is None else (
            virt if terms.covered is None else virt & ~terms.covered)
        own = real_surround(data, gb, seen, aperture_deg, todo, surround_rays, far_bounce)
        e_o, vis, e_r = own if terms.surround is None else (
            dr.select(todo, a, b) for a, b in zip(own, terms.surround, strict=True))
        e_amb = (e_o * dr.maximum(1.0 - terms.z / dr.maximum(vis, 1e-3), 0.0)
                 + ambient_fill(data) * (math.pi * terms.z) + e_r)
    diffuse = gb.albedo * (1.0 / math.pi) * (e_dir + terms.x + e_amb)
    glossy = virt & (dr.max(spec) > 0.0)
    spec_direct = mi.Color3f(0.0)
    far = data.distant
    if dr.any(glossy):
        near = (data.lights if far is None else far.near).lights

        def reflected(p: mi.Point3f, n: mi.Vector3f, v: mi.Vector3f, f0: mi.Color3f,
                      alpha: mi.Float) -> mi.Color3f:
            out = mi.Color3f(0.0)
            for lt in near:
                wi, _ = light_direction(lt, p)
                e_i = direct_irradiance(data.views.mixed, LightSet([lt]), p, n, mi.Bool(True))
                out += ggx_specular(n, v, wi, f0, alpha) * e_i
            return out

        # on the glossy lanes only: over every lane (masked) the lights' shadow rays and GGX
        # made a ~750-op kernel of the whole 640×480×4 G-buffer with seven lights
        spec_direct = on_active(reflected, gb.position, gb.normal, glossy, gb.to_camera, spec,
                                rough)
        if far is not None:  # what the specular cone sees where it leaves the volume
            spec_direct += escape_radiance(data, gb, seen, glossy & ~traced) * (
                1.0 if terms.t is None else terms.t)
    if max(mirror_alpha) > 0:
        spec_direct += ray_mixed
    mixed = dr.select(virt, diffuse + spec_direct + cone, mi.Color3f(0.0))
    dr.eval(mixed, delta, hidden)
    return mixed, delta, hidden


def compose(data: DVCTData, gb: GBuffer, vols: Volumes | None, view: FrameView,
            options: Options, timer: StageTimer | None = None) -> Layers:
    """Cones, upsampling, shading and composition of one frame from its G-buffer and volumes
    (the stages after :func:`build_volumes`; only these read ``shells`` and
    ``level_bias``, so ``benchmarks/tune_realtime.py`` builds the volumes once per world and
    composes each candidate)."""
    timer = timer or StageTimer()
    stats: dict[str, float] = {"lights": float(len(data.lights.lights)),
                               "volume_cell": data.grid.cell if data.grid else 0.0}
    terms = None
    # the photograph where the camera sees a real point: one per frame for the surround,
    # mirror and escape rays
    seen = Reprojector(view.camera, view.frame, data.views.real)
    if vols is not None:
        k = int(options.cone_scale)
        with timer.stage("cones"):
            idx = low_res_lanes(gb, k) if k > 1 else dr.arange(mi.UInt32, dr.width(gb.role))
            full = Lanes(gb.position, gb.normal, gb.to_camera, gb.role, gb.shape)
            low = full.subset(idx) if k > 1 else full
            terms = cone_terms(data, vols, low, options, stats)
            if k > 1 and surround_wanted(data, options):  # the surround at the cones' lanes
                terms = replace(terms, surround=surround_at(
                    data, low, real_fill(data, gb), seen, options.diffuse_aperture_deg,
                    low.role == ROLE_VIRTUAL, options.surround_rays, options.far_bounce))
        if k > 1:
            with timer.stage("upsample"):
                terms = upsample(gb, k, low, terms, vols.alpha.grid.cell)
        stats["vpls_delta"] = float(vols.vpls_delta)
        stats["voxels"] = float(vols.voxels)
    with timer.stage("shade"):
        mixed, delta, hidden = shade(data, gb, terms,
                                     view.frame if options.photo_albedo else None, seen,
                                     options.diffuse_aperture_deg,
                                     options.shadow_samples if options.direct == "rays"
                                     else None, options.surround_rays, options.far_bounce,
                                     (float(options.mirror_alpha),
                                      float(options.mirror_alpha_real)))
    with timer.stage("assemble"):  # −h a B: the occlusion weighting of reflections
        layers = assemble(gb, view.frame, mixed, delta, stats,
                          hidden if terms is not None else None)
    if not data.world.has_virtual:
        assert not np.any(layers.delta), "dvct: delta must vanish without virtual objects"
    return layers


class DVCTMethod(BaseMethod):
    """Delta Voxel Cone Tracing (Franke 2014)."""

    spec = SPEC
    incremental_pose = True

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> DVCTData:
        return prepare(world, options)

    move = staticmethod(pose)  # in place; a moved real shape prepares again

    def relit(self, data: DVCTData, world: World, options: Options) -> DVCTData | None:
        """Light update (issue #32, :meth:`BaseMethod.relight`): the views' emitters set in
        place, the lights reduced again, their cone radii and the proxy's RSMs made again;
        the volume, the proxy's voxels, the triangles and the materials are kept; the
        distant light (:class:`DistantLight`) is made again (its prefilter is cached per
        map)."""
        from arlight.methods.base import relight_views

        if not relight_views(data.views, data.world.lights, world.lights):
            return None
        lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
        maps = None if data.real_maps is None else real_maps(
            data.views, lights, data.grid, options.rsm_size, data.real_maps.box,
            data.real_maps.coverage)
        distant = DistantLight.of(world, lights)
        return replace(data, world=world, lights=lights, real_maps=maps,
                       light_size=_light_sizes(world, lights, options), distant=distant,
                       mirror=mirror_light(data.views, lights, world, distant, options))

    def render_view(self, data: DVCTData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        with timer.stage("gbuffer"):
            gb = render_gbuffer(data.views.mixed, view.camera, options.gbuffer_spp,
                                settings.seed)
        vols = build_volumes(data, options, timer)
        return compose(data, gb, vols, view, options, timer)


__all__ = ["DVCTData", "DVCTMethod", "OPTIONS", "SPEC", "Volumes", "build_volumes",
           "directional_coverage", "place_volume", "proxy_voxels",
           "compose", "cone_error", "cone_terms", "cone_volumes", "diffuse_cone_set",
           "diffuse_cones", "diffuse_visibility", "light_channels",
           "ggx_specular", "inject_regular", "mirror_traced", "inject_split", "prepare", "shade",
           "shadow_cones", "specular_cone", "upsample"]
