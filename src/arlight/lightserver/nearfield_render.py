"""Rendering a client frame with the ``nearfield`` method and a given light state."""

from __future__ import annotations

from arlight.errors import ArlightError


class NearFieldRenderer:
    """Prepare the ``nearfield`` method once for a scene; render any camera with any light."""

    def __init__(self, scene, spp: int = 1):
        from arlight.methods import get_method, load_errors

        try:
            self.method = get_method("nearfield")
        except ArlightError as exc:
            why = load_errors().get("nearfield", "not registered")
            raise ArlightError(f"the nearfield method is not available ({why})") from exc
        self.scene = scene
        self.spp = spp

    def render(self, camera, light):
        raise ArlightError("nearfield rendering with a server light is not wired yet")
