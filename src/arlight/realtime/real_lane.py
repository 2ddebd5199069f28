"""The real pixels' change in ``dir`` and ``dlpv``: its albedo and the softness of the
reduced lights' shadows (issue #33).

Both methods add ``ρ/π ΔE`` to a real pixel (Knecht 2010's differential, Franke Eq. 5.14
with the delta irradiance ``ΔE``). Option ``real_albedo``:

* ``proxy``: ``ρ`` is the proxy's albedo (the G-buffer's, a texture's mean);
* ``photo``: ``ρ̂ = clip(π B / E_r, 0, 1)`` read from the photograph ``B`` under the model's
  irradiance ``E_r`` (:func:`arlight.realtime.photo_albedo.photo_albedo`), so the change is
  ``B ΔE / E_r``, a ratio of the light the pixel receives — right on textured and glossy
  real surfaces where the proxy's mean albedo is not. ``E_r`` holds the reduced lights
  (shadow rays in the real proxy: the direct change's own, which give the real scene's
  visibility where the mixed scene's ray is blocked and say it is clear elsewhere —
  :func:`arlight.realtime.shading.direct_terms_gbuffer`) and the SH remainder; ``dir``
  adds the real scene's indirect light from its VPLs (``R_µ``'s gather, which it computes
  anyway): without it a room's interreflection is missing from ``E_r``, ρ̂ comes out high
  and shadows too deep (12 training worlds: median +0.35 dB with it, +0.19 without, worst
  −0.26 / −0.58).

Option ``shadow_samples``: shadow rays per extended reduced light for the direct change
(:func:`arlight.realtime.shading.direct_change`): a reduced light stands for a region of sky
or a patch of an area light, and one ray makes its shadow as hard as a point's.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews
from arlight.realtime.gbuffer import GBuffer
from arlight.realtime.light_reduction import LightSet
from arlight.scene.schema import Field

ALBEDO_MODES = ("proxy", "photo")
"""Values of ``real_albedo``."""

REAL_LANE_OPTIONS: dict[str, Field] = {
    "real_albedo": Field("choice", "photo", "albedo of the real pixels' change ρ/π ΔE: "
                         "`proxy` (the proxy's, a texture's mean) or `photo` (ρ̂ = "
                         "clip(π B / E_r, 0, 1) from the photograph, the change as a ratio "
                         "B ΔE / E_r; arlight.realtime.real_lane)", choices=ALBEDO_MODES),
    "shadow_samples": Field("int", 8, "shadow rays per extended light (a directional light "
                            "extracted from an environment, an area light's cosine point) "
                            "and real pixel for the direct change: > 1 a soft shadow of the "
                            "region it stands for; 1: a hard one "
                            "(arlight.realtime.shading.direct_change)", "", min=1, max=256),
}
"""The real-lane options of ``dir`` and ``dlpv``."""


def real_albedo(mode: str, views: SceneViews, lights: LightSet, frame: np.ndarray,
                gb: GBuffer, real: mi.Bool, indirect: mi.Color3f | None = None,
                direct: mi.Color3f | None = None) -> mi.Color3f:
    """Per-lane albedo of the real lanes' change (module docstring): the G-buffer's
    (``proxy``) or the photograph's (``photo``, computed on the ``real`` lanes; the proxy's
    elsewhere). ``frame``: ``(H, W, 3)`` linear radiance; ``indirect``: the real scene's
    indirect irradiance (W/m²) where the method has it, added to ``E_r``; ``direct``:
    ``E_r``'s direct part where the method has traced it with its direct change
    (:func:`arlight.realtime.shading.direct_terms_gbuffer`'s ``real``: no shadow rays of
    ``E_r``'s own), None: traced here (one ray per light)."""
    if mode == "proxy":
        return gb.albedo
    if mode != "photo":
        raise ValueError(f"real_albedo must be one of {ALBEDO_MODES}, got {mode!r}")
    from arlight.realtime.photo_albedo import photo_albedo

    return photo_albedo(views.real, lights, frame, gb.pixel, gb.position, gb.normal,
                        gb.albedo, real, indirect, direct)


__all__ = ["ALBEDO_MODES", "REAL_LANE_OPTIONS", "real_albedo"]
