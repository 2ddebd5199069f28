"""The one-bounce reference the real-time methods' tests compare with (issue #33): Mitsuba's
``path`` at max_depth 3 minus max_depth 2 — independent code, one bounce exactly — on the
box scene of ``tests/methods/test_dlpv.py`` (red cube on a white floor, point light), and
the regions the tests read: the cube's pixels and the floor ring around it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mitsuba as mi
import numpy as np
from scipy.ndimage import binary_dilation, binary_erosion

from arlight.backend.mitsuba_scene import mitsuba_sensor
from arlight.realtime.gbuffer import GBuffer

PASSES, SPP = 8, 64
"""Independent passes of the reference and samples per pixel of each."""


def one_bounce(view, camera, passes: int = PASSES, spp: int = SPP) -> np.ndarray:
    """``passes`` independent estimates ``(P, H, W, 3)`` of the one-bounce radiance of the
    Mitsuba scene ``view.scene``: ``path`` at max_depth 3 minus max_depth 2 (same seed per
    pass, so the direct light cancels exactly)."""
    out = []
    for k in range(passes):
        img = [np.array(mi.render(view.scene, sensor=mitsuba_sensor(camera, spp), seed=k,
                                  spp=spp, integrator=mi.load_dict(
                                      {"type": "path", "max_depth": depth})))[..., :3]
               for depth in (2, 3)]
        out.append(img[1] - img[0])
    return np.array(out, np.float64)


@dataclass
class OneBounce:
    """Mitsuba's one-bounce images of a prepared box scene and the regions read.

    Attributes:
        gb: the G-buffer of the mixed view (one sample per pixel centre).
        virt: the cube's pixels eroded by one pixel, ``(H, W)`` bool.
        ring: the floor pixels 2–6 px around the cube, ``(H, W)`` bool.
        mixed: one-bounce radiance of the mixed scene, ``(P, H, W, 3)``.
        delta: its change by the insertion, mixed − real, ``(P, H, W, 3)``.
    """

    gb: GBuffer
    virt: np.ndarray
    ring: np.ndarray
    mixed: np.ndarray
    delta: np.ndarray

    @classmethod
    def of(cls, views, camera) -> OneBounce:
        """The reference of a method's prepared ``views`` (``SceneViews``) seen by
        ``camera``."""
        from arlight.realtime.gbuffer import render_gbuffer

        gb = render_gbuffer(views.mixed, camera, 1, 0)
        role = np.array(gb.role).reshape(camera.height, camera.width)
        virt = binary_erosion(role == 1, iterations=1)
        ring = (binary_dilation(role == 1, iterations=6)
                & ~binary_dilation(role == 1, iterations=1) & (role == 0))
        mixed = one_bounce(views.mixed, camera)
        return cls(gb, virt, ring, mixed, mixed - one_bounce(views.real, camera))

    def means(self) -> tuple[np.ndarray, np.ndarray]:
        """The reference's means (RGB) over passes and pixels: the cube's one-bounce light
        and the ring's change."""
        return (self.mixed[:, self.virt].mean(axis=1).mean(axis=0),
                self.delta[:, self.ring].mean(axis=1).mean(axis=0))

    def assert_precise(self, cube_channels: tuple[int, ...] = (0,)) -> None:
        """The reference's standard errors (over its passes) are ≤ 3 % of the means the
        tests compare with — the cube's light in ``cube_channels``, the ring's green change
        (the cube's shadow on bounce light) and its red − green (the cube's red bounce) — so
        a test's tolerance is the method's error, not the reference's."""
        checks = [(self.mixed, self.virt, [c]) for c in cube_channels]
        checks += [(self.delta, self.ring, [1]), (self.delta, self.ring, [0, 1])]
        for img, reg, ch in checks:
            per = img[:, reg].mean(axis=1)
            x = per[:, ch[0]] - (per[:, ch[1]] if len(ch) == 2 else 0.0)
            assert x.std(ddof=1) / math.sqrt(len(per)) <= 0.03 * abs(x.mean()), (ch, x)
