"""Rendering a client frame with the ``nearfield`` method and a given light state.

A thin adapter over :class:`arlight.methods.nearfield.NearFieldClient` (issue 17): the
method is prepared once for the client's world (PRT transfer, G-buffer set-up); each frame
is rendered for its own camera with whatever :class:`~arlight.nearfield.NearFieldLight` the
caller passes (Rohmer Eq. 14).
"""

from __future__ import annotations

import numpy as np

from arlight.errors import InputError
from arlight.nearfield.state import NearFieldLight
from arlight.scene.model import FrameView

GREY_CARD = 0.18
"""Background radiance (W/(sr·m²)) of a client scene without a frame."""


class NearFieldRenderer:
    """Prepare ``nearfield`` once for ``scene``'s world; render any camera with any light.

    Args:
        scene: the client's AR scene (proxy, virtual objects, camera, background frame; a
            scene without a frame gets a constant grey background).
        spp: G-buffer samples per pixel.
        options: ``nearfield`` method options (e.g. ``{"shadows": "rays"}``).
    """

    def __init__(self, scene, spp: int = 1, options: dict | None = None):
        from arlight.methods import RenderSettings
        from arlight.methods.nearfield import NearFieldClient

        self.scene = scene
        self.n_objects = len(scene.world.virtual_shapes)
        opts = {"gbuffer_spp": int(spp), **(options or {})}
        self.client = NearFieldClient(scene.world, opts, RenderSettings(spp=int(spp)))
        h, w = scene.camera.height, scene.camera.width
        self.background = (scene.frame if scene.frame is not None
                           else np.full((h, w, 3), GREY_CARD, np.float32))

    def check(self, light: NearFieldLight, where: str) -> None:
        """The light must carry one SH block per virtual object of the client's world."""
        if light.n_objects != self.n_objects:
            raise InputError(f"the server sends SH for {light.n_objects} virtual objects, "
                             f"the client scene has {self.n_objects} (the same objects, in "
                             "the same order, are needed)", file=where, field="shapes")

    def render(self, camera, light: NearFieldLight):
        """Layers of the scene seen by ``camera`` (same size as the scene's) under ``light``."""
        view = FrameView(camera=camera, frame=self.background)
        return self.client.render(view, light)
