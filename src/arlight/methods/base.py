"""What every method consumes and produces: render settings and the layer stack.

A method is a function ``render(scene, settings) -> Layers`` registered by name (see
:mod:`arlight.methods`). It computes ``mixed`` (I_m, virtual objects under the real light)
and ``delta`` (I_m − I_r, how the real scene changes); the composite always comes from
:func:`arlight.composite.composite`, so nothing downstream knows which method ran.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from arlight.composite import composite
from arlight.errors import InputError
from arlight.scene.model import ARScene


@dataclass
class RenderSettings:
    """Settings shared by the methods.

    Attributes:
        spp: samples per pixel (stratified, multi-jittered, when a perfect square).
        max_depth: longest path in vertices, Mitsuba's convention (1: emitters seen directly,
            2: direct lighting only, -1: unlimited with Russian roulette).
        rr_depth: path depth from which Russian roulette starts.
        seed: master seed; equal seeds give bitwise identical renders.
        spp_per_pass: samples per wavefront pass (None: as many as fit in ~2M lanes).
        progress: show a progress bar.
        options: method-specific options (documented by each method).
    """

    spp: int = 64
    max_depth: int = 8
    rr_depth: int = 5
    seed: int = 0
    spp_per_pass: int | None = None
    progress: bool = False
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.spp < 1:
            raise InputError(f"must be >= 1, got {self.spp}", field="spp")
        if self.max_depth == 0 or self.max_depth < -1:
            raise InputError(f"must be -1 or >= 1, got {self.max_depth}", field="max_depth")


@dataclass
class Layers:
    """The result of a method; images are ``(H, W, 3)`` float32 linear radiance.

    Attributes:
        background: the camera frame ``I_c``.
        mixed: ``I_m`` — real proxy plus virtual objects.
        delta: ``I_m − I_r`` — the change of the real scene (negative in shadows).
        mask: ``M`` in [0, 1] ``(H, W)`` — virtual coverage, averaged over samples.
        composite: ``M·I_m + (1 − M)·(I_c + delta)`` (Kán Eq. 2.20).
        real: ``I_r`` where the method computes it, else None.
        stderr: per-pixel standard errors of Monte Carlo layers, by layer name.
        stats: timings (``seconds``), counts (``samples``, ``rays``) and rates.
        method: the registered name of the method that produced the layers.
    """

    background: np.ndarray
    mixed: np.ndarray
    delta: np.ndarray
    mask: np.ndarray
    composite: np.ndarray
    real: np.ndarray | None = None
    stderr: dict[str, np.ndarray] = field(default_factory=dict)
    stats: dict[str, float] = field(default_factory=dict)
    method: str = ""

    @staticmethod
    def assemble(background: np.ndarray, mixed: np.ndarray, delta: np.ndarray,
                 mask: np.ndarray, **kwargs) -> Layers:
        """Build layers and the composite through the one shared compositing function."""
        bg = np.asarray(background, dtype=np.float32)
        mixed = np.asarray(mixed, dtype=np.float32)
        delta = np.asarray(delta, dtype=np.float32)
        mask = np.asarray(mask, dtype=np.float32)
        return Layers(background=bg, mixed=mixed, delta=delta, mask=mask,
                      composite=composite(bg, mixed, delta, mask).astype(np.float32), **kwargs)


def differential_samples(mixed, real, mask, background) -> dict:
    """Per-sample layers of a differential Monte Carlo method (Dr.Jit arrays per lane).

    ``delta = L_m − L_r`` per sample (paired, so its standard error is that of the
    difference) and the per-sample composite ``m·L_m + (1 − m)(I_c + delta)``, whose moments
    give the composite's standard error. Feed the dict to :func:`arlight.backend.passes.
    run_passes` and its result to :func:`layers_from_passes`.
    """
    delta = mixed - real
    comp = mask * mixed + (1.0 - mask) * (background + delta)
    return {"mixed": mixed, "real": real, "delta": delta, "mask": mask, "composite": comp}


def layers_from_passes(frame: np.ndarray, result, **stats: float) -> Layers:
    """Layers from the moments of :func:`differential_samples` (a ``PassResult``).

    Layers are the per-pixel means, ``stderr`` their standard errors; ``stats`` gets the
    timing and sample counts (``seconds``, ``samples``, ``spp``, ``samples_per_second``) plus
    the method's own entries.
    """
    mom = result.moments
    samples = result.lanes
    spp = mom["mixed"].count
    base = {"seconds": result.seconds, "samples": float(samples), "spp": float(spp),
            "samples_per_second": samples / max(result.seconds, 1e-9)}
    return Layers.assemble(frame, mom["mixed"].mean, mom["delta"].mean,
                           mom["mask"].mean[..., 0], real=mom["real"].mean,
                           stderr={k: mom[k].stderr for k in ("mixed", "real", "delta",
                                                              "composite")},
                           stats={**base, **stats})


def require_frame(scene: ARScene) -> np.ndarray:
    """The scene's background frame, or an error naming the scene file."""
    if scene.frame is None:
        raise InputError("the scene has no background frame; add a [frame] table with "
                         "`image = ...` (or synthesise one with `arlight synth`)",
                         file=str(scene.source) if scene.source else None, field="frame")
    return scene.frame
