"""Synthetic photographs: the camera frame a "world" would produce, and its ground truth.

A *world* is an AR scene whose real shapes describe the real world (it may hold more detail
than the proxy a method is given) and whose virtual shapes are the objects to insert.
:func:`synthesize` renders

* the frame ``I_c``: the world without virtual objects (what the camera saw),
* the ground truth: the world with the virtual objects (what a perfect method returns),
* the mask: the fraction of each pixel's area whose first hit is a virtual shape,

with **Mitsuba's own renderer only** — :func:`mitsuba.render` with the ``path`` integrator
and a Mitsuba sensor built from the scene's camera (``perspective``, or ``thinlens`` for a
disk aperture; see :func:`arlight.backend.mitsuba_scene.describe_sensor`), an ``hdrfilm``
with a ``box`` filter and one of Mitsuba's samplers (``sampler``; default
:data:`DEFAULT_SAMPLER`, ``multijitter``, see *Samplers* below). It shares no code with
the methods it grades: not their camera rays (:mod:`arlight.backend.camera_rays`), passes
(:mod:`arlight.backend.passes`) or estimators (:mod:`arlight.methods`), so a bug there cannot
cancel out. Only the translation of the scene into Mitsuba objects
(:mod:`arlight.backend.mitsuba_scene`) is shared; tests check it against Mitsuba directly.

**Samplers.** ``multijitter`` (Kensler's correlated multi-jittered sampling: every 2D
dimension of a pixel's ``n`` samples is a jittered ``⌊√n⌋ × ⌈n/⌊√n⌋⌉`` grid, randomised per
seed), ``ldsampler`` (a scrambled (0, 2)-sequence, ``n`` a power of 4), ``orthogonal``
(orthogonal arrays, ``n = p²``, ``p`` prime) or ``independent``. Measured on ``bunny-box``
(80×60, 8 renders each, MSE against a 4096-spp render), the MSE relative to ``independent``
at equal spp was 0.17 / 0.16 / 0.17 for ``multijitter`` at 4 / 16 / 64 spp, 0.19 / 0.16 /
0.17 for ``ldsampler``, 0.19 (4) / 0.24 (9) / 0.17 (25) for ``orthogonal``
(``multijitter``: 0.24 at 9, 0.19 at 25): ``multijitter`` is the default, being as good or
better and accepting most counts. A low-discrepancy sampler renders only certain counts per
pixel (``multijitter`` rounds ``n`` up to ``⌊√n⌋·⌈n/⌊√n⌋⌉``, e.g. 5 → 6), so the plan
(:func:`batch_plan`) only asks for counts it renders exactly (Mitsuba is asked:
:func:`~arlight.backend.mitsuba_scene.sampler_count`).

**Standard errors.** Each image is rendered as ``B`` independent batches with different
seeds — each batch its own randomisation of the sampler — with ``n_b`` samples per pixel
and per-pixel mean ``m_b``. With ``independent``, ``B = min(batches, spp)`` and ``spp`` is
split as evenly as possible (the first ``spp mod B`` batches get one sample more). With a
low-discrepancy sampler the batches are equal, ``n_b = n``: the largest count the sampler
renders exactly that divides ``spp`` with ``B = spp / n ≥ min(batches, spp)`` (e.g. 256 spp
in 64 batches of 4; with ``spp ≤ batches`` batches of 1 sample, no better than
``independent``), so the batch means are independent and identically distributed and their
spread is an honest standard error. A batch's samples are correlated (stratified), so no
per-sample variance is ever used: it would overstate the error of a low-discrepancy mean.
With ``N = Σ n_b``::

    mean   = Σ n_b m_b / N
    s²     = Σ n_b (m_b − mean)² / (B − 1)      (unbiased per-sample variance)
    stderr = sqrt(s² / N)

(``E[Σ n_b (m_b − mean)²] = (B − 1) σ²`` when every sample has variance ``σ²``.) With the
default ``B = 64`` (:data:`DEFAULT_BATCHES`) the standard error itself has 63 degrees of
freedom, so a 3-SE test rejects a correct pixel with probability 0.4 % (Student's t) instead
of 0.27 %; with 16 batches it would be 0.9 %, too close to the 1 % the tests allow. ``spp`` and
``batches`` must both be at least 2. A batch wider than :data:`MAX_LANES` camera samples is
rendered in several chunks so memory stays bounded: with ``independent`` separate renders
with their own seeds, with a low-discrepancy sampler one render in passes of
``samples_per_pass`` (Mitsuba's integrator option; the passes continue one sample set per
pixel, so the batch stays one stratified set).

**Mask.** The coverage view (:func:`arlight.backend.mitsuba_scene.describe_coverage_view`)
gives virtual shapes a white and every other shape a black two-sided diffuse BSDF, without
emitters; Mitsuba's ``aov`` integrator (``albedo``) then returns 1 where a camera ray first
hits a virtual shape and 0 elsewhere, and the box-filtered mean over ``max(spp, 64)``
samples (rounded up to a count the sampler renders exactly) is the covered fraction of the
pixel (error at most the binomial ``0.5/sqrt(spp)`` with ``independent``, less with the
stratified samplers; exactly 0 or 1 for pixels not crossed by an edge). An AOV rather than
unit-radiance area emitters, because Mitsuba's area emitters emit from the front side only:
a card or an open mesh seen from behind would read 0.

**Cache.** Results are cached under ``<cache_dir>/synthetic/<key>.npz``. The key is a
SHA-256 over everything that determines the images (:func:`render_spec`): the plain-data
descriptions of both views (geometry, materials, emitters, decoded textures and
environment maps), the sensor (with its sampler), the integrators, the sample plan and
seeds, Mitsuba's
version, :data:`FORMAT_VERSION` and — when a Phong material is used — the source of the
Python Phong plugin. The render itself is driven by the same description, so the key cannot
miss an input of the render; names and other image-neutral edits leave it unchanged. A
corrupt or truncated cache file is treated as a miss and rendered again.
"""

from __future__ import annotations

import hashlib
import importlib.util
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import (
    describe_coverage_view,
    describe_sensor,
    describe_views,
    load_scene,
    load_sensor,
    phong_plugin_name,
    plugin_dict,
    sampler_count,
    virtual_names,
)
from arlight.cache import default_cache_dir
from arlight.content_hash import content_hash
from arlight.errors import InputError
from arlight.interrupts import shielded, test_point
from arlight.io.images import atomic_write
from arlight.jit import MAX_LANES, ensure_variant
from arlight.progress import task
from arlight.scene.model import ARScene

FORMAT_VERSION = 2
"""Bump when this module changes how the images are rendered (seeds, plans, estimators)."""
MIN_MASK_SPP = 64
"""Fewest samples per pixel of the mask render."""

_IMAGES = ("frame", "frame_stderr", "ground_truth", "ground_truth_stderr", "mask")

DEFAULT_BATCHES = 64  # independent batches behind each standard error (see above)
SAMPLERS = ("multijitter", "ldsampler", "orthogonal", "independent")
"""Mitsuba samplers :func:`synthesize` accepts (see the module docstring)."""
DEFAULT_SAMPLER = "multijitter"
"""The sampler of the synthetic photos: lowest measured error at equal spp (module docstring)."""


@dataclass
class SyntheticPhoto:
    """A synthetic camera frame and the ground truth of the same world with virtual objects.

    Images are ``(H, W, 3)`` float32 linear radiance (W·sr⁻¹·m⁻²); ``mask`` is the virtual
    coverage ``(H, W)`` in [0, 1]; ``*_stderr`` are per-pixel standard errors of the Monte
    Carlo means (same units as the images).
    """

    frame: np.ndarray
    frame_stderr: np.ndarray
    ground_truth: np.ndarray
    ground_truth_stderr: np.ndarray
    mask: np.ndarray
    spp: int
    seed: int
    key: str = ""


# --------------------------------------------------------------------------------------------
# What determines the images
# --------------------------------------------------------------------------------------------

def check_sampler(sampler: str) -> None:
    """Raise :class:`InputError` (field ``sampler``) unless ``sampler`` is in :data:`SAMPLERS`."""
    if sampler not in SAMPLERS:
        raise InputError(f"unknown sampler {sampler!r} (expected one of {', '.join(SAMPLERS)})",
                         field="sampler")


def batch_plan(spp: int, batches: int, sampler: str = "independent") -> list[int]:
    """Samples per pixel of each batch, summing to ``spp``.

    ``independent``: ``min(batches, spp)`` batches, sizes differing by at most one (larger
    ones first). A low-discrepancy ``sampler``: ``spp / n`` equal batches of the largest
    ``n`` that ``sampler`` renders exactly
    (:func:`~arlight.backend.mitsuba_scene.sampler_count`), divides ``spp`` and
    leaves at least ``min(batches, spp)`` batches (see the module docstring).

    Raises:
        InputError: ``spp < 2`` or ``batches < 2`` (no standard error from one batch), or an
            unknown sampler.
    """
    check_sampler(sampler)
    if batches < 2:
        raise InputError(f"must be >= 2 to estimate a standard error, got {batches}",
                         field="batches")
    if spp < 2:
        raise InputError(f"must be >= 2 (one sample per batch, at least two batches), "
                         f"got {spp}", field="spp")
    b = min(batches, spp)
    if sampler != "independent":
        n = max(v for v in range(1, spp // b + 1)
                if spp % v == 0 and (v == 1 or sampler_count(sampler, v) == v))
        if sampler_count(sampler, n) != n:  # a sampler that cannot render 1 sample
            raise InputError(f"the {sampler} sampler cannot split {spp} spp into at least "
                             f"{b} equal batches it renders exactly", field="spp")
        return [n] * (spp // n)
    q, r = divmod(spp, b)
    return [q + 1] * r + [q] * (b - r)


def mask_count(spp: int, sampler: str) -> int:
    """Samples per pixel of the mask: ``max(spp, MIN_MASK_SPP)``, rounded up to a count
    ``sampler`` renders exactly."""
    return sampler_count(sampler, max(spp, MIN_MASK_SPP))


def _passes(n: int, pixels: int) -> int:
    """Samples per pass of a one-render batch of ``n`` samples per pixel: the largest divisor
    of ``n`` with at most :data:`MAX_LANES` camera samples per pass (at least 1)."""
    per = max(1, MAX_LANES // max(pixels, 1))
    return max(d for d in range(1, min(n, per) + 1) if n % d == 0)


def _chunks(n: int, pixels: int) -> list[int]:
    """Split ``n`` samples per pixel into renders of at most :data:`MAX_LANES` samples."""
    per = max(1, MAX_LANES // max(pixels, 1))
    return [min(per, n - k) for k in range(0, n, per)]


def _seed(seed: int, stream: str, batch: int, chunk: int) -> int:
    """32-bit sampler seed of one render, distinct per (seed, stream, batch, chunk).

    The SHA-256 of the plain text, not :func:`~arlight.content_hash.content_hash` (whose
    type-tagged encoding gives other numbers): the seeds, hence the ground-truth images,
    stay as they were."""
    text = f"{seed}:{stream}:{batch}:{chunk}".encode()
    return int.from_bytes(hashlib.sha256(text).digest()[:4], "little")


def _uses_phong(node: Any, name: str) -> bool:
    if isinstance(node, dict):
        return node.get("type") == name or any(_uses_phong(v, name) for v in node.values())
    if isinstance(node, list):
        return any(_uses_phong(v, name) for v in node)
    return False


def render_spec(world: ARScene, spp: int = 256, seed: int = 1, max_depth: int = 8,
                rr_depth: int = 5, batches: int = DEFAULT_BATCHES,
                sampler: str = DEFAULT_SAMPLER) -> dict[str, Any]:
    """Everything that determines the images of :func:`synthesize`, as plain data.

    ``views`` (real and mixed), ``coverage`` (the mask's view), ``sensor`` (with the
    ``sampler``), ``integrators`` and ``plan`` are what :func:`_render` hands to Mitsuba;
    ``mitsuba``, ``format`` and ``phong_source`` stand for the code that interprets them.
    """
    ensure_variant()
    plan = batch_plan(spp, batches, sampler)
    mask_spp = max(spp, MIN_MASK_SPP) if sampler == "independent" else mask_count(spp, sampler)
    sensor = describe_sensor(world.camera, spp)
    if sampler != "independent":  # a count it renders (the renders set their own)
        sensor["sampler"] = {"type": sampler, "sample_count": plan[0]}
    views = describe_views(world)
    spec: dict[str, Any] = {
        "format": FORMAT_VERSION,
        "mitsuba": mi.__version__,
        "views": views,
        "coverage": describe_coverage_view(views["mixed"], virtual_names(world)),
        "has_virtual": world.has_virtual,
        "sensor": sensor,
        "integrators": {"radiance": {"type": "path", "max_depth": int(max_depth),
                                     "rr_depth": int(rr_depth)},
                        "coverage": {"type": "aov", "aovs": "coverage:albedo"}},
        "plan": {"seed": int(seed), "batches": plan, "mask_spp": mask_spp,
                 "max_lanes": MAX_LANES},
    }
    name = phong_plugin_name()
    if _uses_phong(views, name):
        spec["phong_source"] = _module_source("arlight.backend.phong")
    return spec


def _module_source(module: str) -> str:
    spec = importlib.util.find_spec(module)
    assert spec is not None and spec.origin is not None
    return Path(spec.origin).read_text(encoding="utf-8")


def _ordered(x: Any) -> Any:
    """``x`` with every dict replaced by one keyed by ``(position, key)``: the content hash
    sorts a dict's items, but here the order counts (the order of a view's objects is the
    scene order). Spec dicts have string keys only, so no spec dict reads like a converted
    one."""
    if isinstance(x, dict):
        return {(i, k): _ordered(v) for i, (k, v) in enumerate(x.items())}
    if isinstance(x, list | tuple):
        return [_ordered(v) for v in x]
    return x


def spec_key(spec: dict[str, Any]) -> str:
    """The cache key of a :func:`render_spec`: 32 hex digits of its
    :func:`~arlight.content_hash.content_hash` (dicts in insertion order)."""
    return content_hash(_ordered(spec), length=32)


def content_key(world: ARScene, spp: int = 256, seed: int = 1, max_depth: int = 8,
                rr_depth: int = 5, batches: int = DEFAULT_BATCHES,
                sampler: str = DEFAULT_SAMPLER) -> str:
    """Cache key of :func:`synthesize` with these settings (see :func:`render_spec`)."""
    return spec_key(render_spec(world, spp=spp, seed=seed, max_depth=max_depth,
                                rr_depth=rr_depth, batches=batches, sampler=sampler))


# --------------------------------------------------------------------------------------------
# Synthesis and the cache
# --------------------------------------------------------------------------------------------

def synthesize(world: ARScene, spp: int = 256, seed: int = 1, max_depth: int = 8,
               rr_depth: int = 5, cache_dir: Path | str | None = None, use_cache: bool = True,
               progress: bool = False, batches: int = DEFAULT_BATCHES,
               sampler: str = DEFAULT_SAMPLER) -> SyntheticPhoto:
    """Render (or load from the cache) the frame, ground truth and mask of ``world``.

    Args:
        world: the world scene (real shapes = the real world, virtual shapes = insertions).
        spp: samples per pixel of the frame and of the ground truth (>= 2); the mask gets
            ``max(spp, 64)``.
        seed: master seed; frame, ground truth, mask and every batch get their own seeds.
        max_depth, rr_depth: path depth settings of Mitsuba's ``path`` integrator.
        cache_dir: cache root (default :func:`default_cache_dir`).
        use_cache: read and write the cache.
        progress: show a progress bar over the batches.
        batches: independent batches the standard errors come from (>= 2; at most ``spp``
            are used with ``independent``; a low-discrepancy sampler uses equal batches, at
            least ``min(batches, spp)`` of them, see :func:`batch_plan`).
        sampler: Mitsuba sampler of every batch (:data:`SAMPLERS`; each batch is its own
            randomisation).

    Raises:
        InputError: bad ``spp``/``batches``/``sampler``, or a camera Mitsuba cannot represent
            (square aperture, non-square pixels, off-centre principal point with a lens).
    """
    spec = render_spec(world, spp=spp, seed=seed, max_depth=max_depth, rr_depth=rr_depth,
                       batches=batches, sampler=sampler)
    key = spec_key(spec)
    path = Path(cache_dir or default_cache_dir()) / "synthetic" / f"{key}.npz"
    shape = (world.camera.height, world.camera.width)
    if use_cache:
        cached = _read_cache(path, shape)
        if cached is not None:
            return SyntheticPhoto(**cached, spp=spp, seed=seed, key=key)
    images = _render(spec, progress=progress)
    if use_cache:
        with atomic_write(path, ".npz") as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **images)
    return SyntheticPhoto(**images, spp=spp, seed=seed, key=key)


def _read_cache(path: Path, shape: tuple[int, int]) -> dict[str, np.ndarray] | None:
    """The cached images, or None when the file is missing, unreadable or malformed."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            images = {k: z[k] for k in _IMAGES}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error):
        return None
    for k, a in images.items():
        if a.shape != (shape if k == "mask" else (*shape, 3)) or a.dtype != np.float32:
            return None
    return images


def _render(spec: dict[str, Any], progress: bool = False) -> dict[str, np.ndarray]:
    """Render the images of a :func:`render_spec` with :func:`mitsuba.render`."""
    ensure_variant()
    plan = spec["plan"]
    sensor = load_sensor(spec["sensor"])
    real = load_scene(spec["views"]["real"])
    mixed = load_scene(spec["views"]["mixed"]) if spec["has_virtual"] else real
    film = spec["sensor"]["film"]
    pixels = film["width"] * film["height"]
    one_set = spec["sensor"]["sampler"]["type"] != "independent"
    mask_plan = [plan["mask_spp"]] if spec["has_virtual"] else []
    bar = task("synthetic photo (batches)", 2 * len(plan["batches"]) + len(mask_plan),
               enabled=progress)
    loaded: dict[tuple[str, int], Any] = {}

    def integrator(kind: str, n: int) -> Any:
        """The integrator ``kind`` for batches of ``n`` spp (in passes with an LD sampler)."""
        per = _passes(n, pixels) if one_set else n
        if (kind, per) not in loaded:
            node = dict(spec["integrators"][kind])
            if per < n:
                node["samples_per_pass"] = per
            loaded[kind, per] = mi.load_dict(plugin_dict(node))
        return loaded[kind, per]

    def render(scene: mi.Scene, kind: str, stream: str, b: int, n: int) -> np.ndarray:
        total = None
        for c, m in enumerate([n] if one_set else _chunks(n, pixels)):
            test_point("kernel")
            with shielded():  # a Ctrl-C waits for the render call (see arlight.interrupts)
                img = mi.render(scene, sensor=sensor, integrator=integrator(kind, m), spp=m,
                                seed=_seed(plan["seed"], stream, b, c))
            part = np.array(img, dtype=np.float64) * m
            total = part if total is None else total + part
        bar.advance()
        assert total is not None
        return total / n

    def mean_and_stderr(scene: mi.Scene, stream: str) -> tuple[np.ndarray, np.ndarray]:
        # weighted Welford update over batch means (West 1979): unbiased s² with B - 1 dof
        n_tot, mean, m2 = 0, None, None
        for b, n in enumerate(plan["batches"]):
            x = render(scene, "radiance", stream, b, n)
            if mean is None:
                n_tot, mean, m2 = n, x, np.zeros_like(x)
                continue
            n_tot += n
            delta = x - mean
            mean = mean + delta * (n / n_tot)
            m2 = m2 + n * delta * (x - mean)
        assert mean is not None and m2 is not None
        var = m2 / (len(plan["batches"]) - 1)
        return mean.astype(np.float32), np.sqrt(var / n_tot).astype(np.float32)

    try:
        frame, frame_se = mean_and_stderr(real, "frame")
        gt, gt_se = mean_and_stderr(mixed, "ground_truth")
        if mask_plan:
            coverage = load_scene(spec["coverage"])
            mask = render(coverage, "coverage", "mask", 0, mask_plan[0])[..., 0]
        else:
            mask = np.zeros(frame.shape[:2])
    finally:
        bar.close()
    return {"frame": frame, "frame_stderr": frame_se, "ground_truth": gt,
            "ground_truth_stderr": gt_se, "mask": np.clip(mask, 0.0, 1.0).astype(np.float32)}


__all__ = ["DEFAULT_SAMPLER", "FORMAT_VERSION", "SAMPLERS", "SyntheticPhoto", "batch_plan",
           "check_sampler", "content_key", "mask_count", "render_spec",
           "spec_key", "synthesize"]


# --------------------------------------------------------------------------------------------
# Depth
# --------------------------------------------------------------------------------------------

def sensor_depth(world: ARScene) -> np.ndarray:
    """What a depth sensor at the world's camera reads: ``(H, W)`` float32 camera-space
    ``z`` (m, along the camera's +z axis) of the first *real* surface through each pixel
    centre (virtual objects are not in the real world), NaN where nothing is hit.

    Rays come from Mitsuba's own sensor for the camera (:func:`describe_sensor`; a thin
    lens is sampled at its centre) and are intersected with Mitsuba's scene of the real
    view, like the photographs themselves.
    """
    ensure_variant()
    cam = world.camera
    scene = load_scene(describe_views(world.without_virtual())["real"])
    sensor = load_sensor(describe_sensor(cam, 1))
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    film = mi.Point2f(((cols.ravel() + 0.5) / cam.width).astype(np.float32),
                      ((rows.ravel() + 0.5) / cam.height).astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    pose = np.asarray(cam.world_from_camera, dtype=np.float64)
    p = np.stack([np.asarray(c, dtype=np.float64) for c in (si.p.x, si.p.y, si.p.z)], axis=1)
    z = (p - pose[:3, 3]) @ pose[:3, 2]
    z[~np.asarray(si.is_valid())] = np.nan
    return z.reshape(cam.height, cam.width).astype(np.float32)
