"""Gruber's Table 1 experiment on synthetic sequences: dominant-direction accuracy, SH error
and time per frame of the variants RM, REG4, REG8, ART1, ART4, ART8.

Each sequence (:func:`arlight.probeless.synthetic_rgbd.render_sequence`) is reconstructed from its
own RGB-D frames with the TSDF (2 m, 268³), and every variant runs the whole sequence on that
reconstruction with the rendered frames as observations, as Gruber et al. replaced the RGB
input by renderings under a known light. Per frame: ``dot(d_est, d_true)`` (their measure),
the relative SH coefficient error ``‖l − l_true‖/‖l_true‖``, the RMS radiance error over the
upper hemisphere relative to its RMS (the lower one is under the floor: unobservable), and
the seconds of RT + estimation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.layers import composite
from arlight.probeless.directions import SH_ORDER, fibonacci_sphere
from arlight.probeless.pipeline import VARIANTS, Pipeline, Settings
from arlight.probeless.reconstruct import reconstruct
from arlight.probeless.synthetic_rgbd import (
    ALBEDO,
    SyntheticFrame,
    incident_sh,
    render_sequence,
)
from arlight.scene.model import Shape, World
from arlight.sphere import sh as SH


@dataclass
class VariantScore:
    """Per-frame measures of one variant on one sequence (arrays over frames).

    ``env_error``: median over equirect pixels of ``|L_est − L_true|`` (luminance) relative
    to the true map's mean (Gruber's environment-map measure, on a lat-long map instead of
    a cube map). ``msad``: with virtual objects, the sum over pixels of the absolute
    composite difference to RM's composite of the same frame (Gruber's MSAD before the
    median over frames; 0 for RM itself); ``shade_seconds``: the shading (E7, upsampling).
    """

    dot: np.ndarray
    sh_error: np.ndarray
    upper_error: np.ndarray
    env_error: np.ndarray
    seconds: np.ndarray
    rays: np.ndarray
    msad: np.ndarray | None = None
    shade_seconds: np.ndarray | None = None


def upper_hemisphere_error(sh: np.ndarray, true_sh: np.ndarray) -> float:
    """RMS of the radiance difference over upward directions (luminance), relative to the
    true radiance's RMS there."""
    d = fibonacci_sphere(4000)
    d = d[d[:, 1] > 0]
    Y = SH.sh_basis(d, SH_ORDER)
    est, true = (Y @ sh) @ SH.LUMINANCE, (Y @ true_sh) @ SH.LUMINANCE
    return float(np.sqrt(np.mean((est - true) ** 2)) / np.sqrt(np.mean(true ** 2)))


def envmap_error(sh: np.ndarray, true_sh: np.ndarray, height: int = 32) -> float:
    """Median absolute luminance difference of the two SH lights on an equirect map,
    relative to the true map's mean luminance."""
    est = SH.sh_to_equirect(sh, height) @ SH.LUMINANCE
    true = SH.sh_to_equirect(true_sh, height) @ SH.LUMINANCE
    return float(np.median(np.abs(est - true)) / np.mean(np.abs(true)))


def score_sequence(frames: list[SyntheticFrame], variants: list[str] | None = None,
                   settings: Settings | None = None, virtual: list[Shape] | None = None
                   ) -> dict[str, VariantScore]:
    """Reconstruct ``frames`` and run each variant over them; with ``virtual`` shapes the
    frames are also shaded (E7) and composited, and compared with RM's composites."""
    mesh = reconstruct([f.rgbd for f in frames], albedo=ALBEDO)
    shapes = [mesh, *(virtual or [])]
    views = build_views(World(shapes=shapes, lights=[]))
    names = variants or list(VARIANTS)
    if virtual and "RM" not in names:
        names = ["RM", *names]
    out: dict[str, VariantScore] = {}
    reference: list[np.ndarray] = []
    for name in names:
        pipe = Pipeline(views, name, settings, shapes=shapes)
        rows, msad, shade = [], [], []
        for i, f in enumerate(frames):
            r = pipe.process(f.rgbd.camera, f.rgbd.colour, f.rgbd.depth,
                             shade=bool(virtual))
            rows.append((float(r.fit.direction @ f.true_direction),
                         float(np.linalg.norm(r.fit.sh - f.true_sh)
                               / np.linalg.norm(f.true_sh)),
                         upper_hemisphere_error(r.fit.sh, f.true_sh),
                         envmap_error(r.fit.sh, f.true_sh),
                         r.stats["time_rt"] + r.stats["time_estimate"], r.stats["rays"]))
            if virtual:
                comp = composite(f.rgbd.colour, r.mixed, r.delta, r.mask)
                if name == "RM":
                    reference.append(comp)
                msad.append(float(np.abs(comp - reference[i]).sum()))
                shade.append(r.stats["time_shade"])
        a = np.array(rows)
        out[name] = VariantScore(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5],
                                 np.array(msad) if virtual else None,
                                 np.array(shade) if virtual else None)
    return out


def table1(n: int = 8, width: int = 160, height: int = 120, spp: int = 64,
           lights: dict[str, tuple[str, Path | None]] | None = None,
           variants: list[str] | None = None, virtual: list[Shape] | None = None
           ) -> dict[tuple[str, bool], dict[str, VariantScore]]:
    """Scores for every (light, moving camera) sequence; ``lights``: label -> (kind, HDR
    file or None), default the SH cap light and the bundled HDR map; ``virtual``: objects
    to insert for the image comparison against RM."""
    res = {}
    for label, (kind, hdr) in (lights or {"sh": ("sh", None), "hdr": ("hdr", None)}).items():
        for moving in (False, True):
            frames = render_sequence(kind, n=n, moving=moving, width=width, height=height,
                                     spp=spp, hdr=hdr)
            res[(label, moving)] = score_sequence(frames, variants, virtual=virtual)
    return res


def object_centre(world: World) -> np.ndarray:
    """Centre of the bounding box of ``world``'s virtual objects (world space, m)."""
    from arlight.nearfield.pipeline import virtual_objects

    objs = virtual_objects(world)
    if not objs:
        raise ValueError("the world has no virtual object")
    v = np.concatenate([o.vertices for o in objs])
    return (v.min(axis=0) + v.max(axis=0)) / 2


__all__ = ["VariantScore", "envmap_error", "incident_sh", "object_centre", "score_sequence",
           "table1", "upper_hemisphere_error"]
