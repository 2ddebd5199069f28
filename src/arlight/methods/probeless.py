"""``probeless``: light estimated from the frame itself, SH differential rendering (Gruber 2014).

Gruber, Langlotz, Sen, Höllerer, Schmalstieg, "Efficient and Robust Radiance Transfer for
Probeless Photorealistic Augmented Reality", IEEE VR 2014 (equation numbers E3, E5, E7 as in
``docs/methods/probeless.md``). No light probe and no scene lights: the light
is the 16-coefficient SH that best explains how the real proxy (a reconstruction) is shaded in
the camera frame (E5), using the proxy's short-range radiance transfer (E3: 81 world-fixed
directions, visibility up to 10 cm). The same transfer, with the virtual objects added, renders
them (E7):

* virtual pixels ``a_v/π T_mix·l`` plus a Phong lobe along the dominant direction (E8) for
  Phong materials;
* real pixels ``delta = a/π (T_mix − T_real)·l`` (option ``ratio``: ``I_c (T_mix·l /
  T_real·l − 1)``), so without a virtual object the frame comes back unchanged.

Options choose the paper's variants (``RM``, ``REG4``, ``REG8``, ``ART1``, ``ART4``, ``ART8``).
One call renders one frame with a fresh state, so the temporal parts of ART (interleaving
over frames, the visibility-state cache) start empty and every direction subset is rebuilt:
they pay off in sequences run through :class:`arlight.probeless.pipeline.Pipeline` (as
``arlight light probeless`` does). The scene's own lights are ignored (that is the point).

Stats: ``rays``, ``samples``, ``dense_samples``, ``light_condition``, ``light_rank``,
``light_confidence``, ``light_dir_x/y/z``; stages ``trace`` (RT), ``estimate``, ``assemble``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arlight.backend.mitsuba_scene import SceneViews, build_views
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
    place_views,
    relight_views,
    require_frame,
)
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.probeless.estimate import DEFAULT_RIDGE
from arlight.probeless.pipeline import VARIANTS, Pipeline, Settings
from arlight.probeless.transfer import MAX_DISTANCE
from arlight.scene.model import FrameView, World
from arlight.timing import StageTimer

OPTIONS: dict[str, Field] = {
    "variant": Field("choice", "ART4", "Gruber's variant: RM (every pixel, all rays), REG4/"
                     "REG8 (regular grid), ART1/4/8 (adaptive + interleaved + state cache)",
                     choices=tuple(VARIANTS)),
    "ratio": Field("bool", False, "real pixels by the ratio form I_c·T_mix·l/T_real·l of E7 "
                   "instead of the additive a/π (T_mix − T_real)·l"),
    "max_distance": Field("float", MAX_DISTANCE, "visibility ray length (Gruber: 10 cm)", "m",
                          min=1e-3, max=10.0),
    "ridge": Field("float", DEFAULT_RIDGE, "Tikhonov weight of the light fit relative to σ_max² "
                   "(damps light directions the scene does not see)", "", min=0.0, max=1.0),
}

SPEC = MethodSpec(
    name="probeless",
    description="Probeless SH light from the frame and SH differential rendering with "
                "10 cm radiance transfer (Gruber et al. 2014).",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, materials=frozenset({"diffuse", "phong"})),
)


@dataclass
class ProbelessData:
    """The world and its Mitsuba views (real proxy / mixed)."""

    world: World
    views: SceneViews


class ProbelessMethod(BaseMethod):
    """Gruber et al. 2014: probeless light estimation and SH differential rendering."""

    spec = SPEC

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> ProbelessData:
        return ProbelessData(world, build_views(world))

    incremental_pose = True

    def move(self, data: ProbelessData, world: World, transforms: dict[str, np.ndarray],
             options: Options) -> ProbelessData | None:
        """``data`` (prepared for ``world`` in any pose) moved in place to
        ``world.posed(transforms)`` (issue #32): the shapes move in both Mitsuba views, real
        ones too (:func:`~arlight.methods.base.place_views`); nothing else is prepared — the
        transfer (E3) is traced from the views every frame. Bitwise the data
        :meth:`prepare_world` makes of the posed world; None (prepare again) when the views hold
        another world."""
        posed = place_views(data.views, world, transforms, real_moves=True)
        return None if posed is None else ProbelessData(posed, data.views)

    def relit(self, data: ProbelessData, world: World, options: Options
              ) -> ProbelessData | None:
        """Light update (issue #32): the scene's lights are not used (the light is estimated
        from the frame); only the views' emitters follow."""
        ok = relight_views(data.views, data.world.lights, world.lights)
        return ProbelessData(world, data.views) if ok else None

    def render_view(self, data: ProbelessData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        frame = require_frame(view, data.world.source)
        st = Settings(max_distance=options.max_distance, ratio=options.ratio,
                      ridge=options.ridge)
        pipe = Pipeline(data.views, options.variant, st, shapes=data.world.shapes)
        with timer.stage("trace"):
            res = pipe.process(view.camera, frame, view.depth, shade=True)
        s = res.stats
        fit = res.fit
        with timer.stage("assemble"):
            layers = Layers.assemble(frame, res.mixed, res.delta, res.mask, stats={
                "rays": s["rays"], "samples": s["samples"],
                # parts of the stage `trace` (not stages: ``time_*`` keys add up to the total)
                "dense_samples": s["dense_samples"], "trace_rt_seconds": s["time_rt"],
                "trace_estimate_seconds": s["time_estimate"],
                "light_condition": float(min(fit.condition, 1e300)),
                "light_rank": float(fit.rank), "light_confidence": fit.confidence,
                "light_dir_x": float(fit.direction[0]), "light_dir_y": float(fit.direction[1]),
                "light_dir_z": float(fit.direction[2])})
        if not data.world.has_virtual:
            assert not np.any(layers.delta), "probeless: delta must vanish without virtual"
        return layers


__all__ = ["OPTIONS", "SPEC", "ProbelessData", "ProbelessMethod"]
