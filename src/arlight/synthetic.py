"""Synthetic photographs: the camera frame a "world" would produce, and its ground truth.

A *world* is an AR scene file whose real shapes describe the real world (it may hold more
detail than the proxy a method is given) and whose virtual shapes are the objects to insert.
:func:`synthesize` path traces

* the frame ``I_c``: the world without virtual objects (what the camera saw), and
* the ground truth: the world with the virtual objects (what a perfect method returns),

with independent seeds, each with a per-pixel standard error, and caches the result on disk
keyed by a hash of the world's content (scene dictionary and referenced files), the settings
and the arlight version, so tests and benchmarks render each photograph once.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import arlight
from arlight.io.images import atomic_write
from arlight.scene.model import ARScene

GT_SEED_OFFSET = 7919  # keeps frame and ground-truth noise independent


@dataclass
class SyntheticPhoto:
    """A synthetic camera frame and the ground truth of the same world with virtual objects.

    Images are ``(H, W, 3)`` float32 linear radiance; ``mask`` is the virtual coverage
    ``(H, W)``; ``*_stderr`` are per-pixel standard errors of the Monte Carlo means.
    """

    frame: np.ndarray
    frame_stderr: np.ndarray
    ground_truth: np.ndarray
    ground_truth_stderr: np.ndarray
    mask: np.ndarray
    spp: int
    seed: int
    key: str = ""


def default_cache_dir() -> Path:
    """``$ARLIGHT_CACHE`` or ``~/.cache/arlight`` (the synthetic photos live in ``synthetic/``)."""
    return Path(os.environ.get("ARLIGHT_CACHE", Path.home() / ".cache" / "arlight"))


def _renderer_fingerprint() -> bytes:
    """Mitsuba's version and the source of the modules that produce the images, so a change
    to the renderer invalidates cached photographs."""
    import mitsuba as mi

    from arlight.backend import camera_rays, mitsuba_scene, passes, phong
    from arlight.methods import reference

    h = hashlib.sha256(mi.__version__.encode())
    for mod in (camera_rays, mitsuba_scene, passes, phong, reference):
        h.update(Path(mod.__file__).read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.digest()


def content_key(world: ARScene, **settings) -> str:
    """SHA-256 over the world's dictionary, the bytes of every file it references, the
    settings, the arlight version and the renderer's source (:func:`_renderer_fingerprint`)."""
    h = hashlib.sha256(_renderer_fingerprint())
    h.update(json.dumps(world.raw, sort_keys=True, default=str).encode())
    cam = world.camera  # the camera actually used, even if raw was edited by hand
    h.update(json.dumps([cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                         np.asarray(cam.world_from_camera).tolist(), cam.aperture_radius,
                         cam.focus_distance, cam.aperture_shape]).encode())
    for path in sorted(_referenced_files(world.raw)):
        h.update(path.encode())
        h.update(Path(path).read_bytes())
    h.update(json.dumps(settings, sort_keys=True).encode())
    h.update(arlight.__version__.encode())
    return h.hexdigest()[:32]


def _referenced_files(node) -> set[str]:
    out: set[str] = set()
    if isinstance(node, dict):
        for k, v in node.items():
            if k in ("file", "image", "texture") and isinstance(v, str) and Path(v).is_file():
                out.add(v)
            else:
                out |= _referenced_files(v)
    elif isinstance(node, list):
        for v in node:
            out |= _referenced_files(v)
    return out


def synthesize(world: ARScene, spp: int = 256, seed: int = 1, max_depth: int = 8,
               rr_depth: int = 5, cache_dir: Path | str | None = None, use_cache: bool = True,
               progress: bool = False) -> SyntheticPhoto:
    """Render (or load from the cache) the frame and ground truth of ``world``.

    Args:
        world: the world scene (real shapes = the real world, virtual shapes = insertions).
        spp: samples per pixel of both renders.
        seed: seed of the frame render; the ground truth uses ``seed + GT_SEED_OFFSET``.
        max_depth, rr_depth: path depth settings (Mitsuba convention).
        cache_dir: cache root (default :func:`default_cache_dir`).
        use_cache: read and write the cache.
        progress: show progress bars.
    """
    settings = dict(spp=spp, seed=seed, max_depth=max_depth, rr_depth=rr_depth)
    key = content_key(world, **settings)
    path = Path(cache_dir or default_cache_dir()) / "synthetic" / f"{key}.npz"
    if use_cache and path.is_file():
        with np.load(path) as z:
            return SyntheticPhoto(**{k: z[k] for k in ("frame", "frame_stderr", "ground_truth",
                                                       "ground_truth_stderr", "mask")},
                                  spp=spp, seed=seed, key=key)
    photo = _render(world, key=key, progress=progress, **settings)
    if use_cache:
        with atomic_write(path, ".npz") as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, frame=photo.frame, frame_stderr=photo.frame_stderr,
                                    ground_truth=photo.ground_truth,
                                    ground_truth_stderr=photo.ground_truth_stderr,
                                    mask=photo.mask)
    return photo


def _render(world: ARScene, spp: int, seed: int, max_depth: int, rr_depth: int, key: str,
            progress: bool) -> SyntheticPhoto:
    from arlight.backend.mitsuba_scene import build_views
    from arlight.backend.passes import run_passes
    from arlight.methods.base import RenderSettings
    from arlight.methods.reference import path_integrator, trace_radiance, virtual_coverage

    views = build_views(world)
    integrator = path_integrator(RenderSettings(max_depth=max_depth, rr_depth=rr_depth))

    def kernel_for(view, with_mask: bool):
        def kernel(rays, pixel, s, lanes):
            out = {"radiance": trace_radiance(integrator, view, rays, s, lanes)}
            if with_mask:
                out["mask"] = virtual_coverage(view, rays)
            return out
        return kernel

    frame = run_passes(world.camera, spp, kernel_for(views.real, False), seed=seed,
                       progress="frame" if progress else None).moments
    gt = run_passes(world.camera, spp, kernel_for(views.mixed, True),
                    seed=seed + GT_SEED_OFFSET,
                    progress="ground truth" if progress else None).moments
    f32 = np.float32
    return SyntheticPhoto(frame=frame["radiance"].mean.astype(f32),
                          frame_stderr=frame["radiance"].stderr.astype(f32),
                          ground_truth=gt["radiance"].mean.astype(f32),
                          ground_truth_stderr=gt["radiance"].stderr.astype(f32),
                          mask=gt["mask"].mean[..., 0].astype(f32), spp=spp, seed=seed, key=key)
