"""Pixel estimates from many samples, in passes, with per-pixel standard errors.

A render of ``spp`` samples per pixel is split into passes of ``spp_per_pass`` samples so
memory stays bounded; each pass is one wavefront of ``n · W · H`` lanes laid out
pixel-major (lane ``l`` → pixel ``l // n``, sample ``l % n``), so a pixel's samples are
neighbours (coherent rays) and the per-pixel sums are block reductions done by Dr.Jit in
the same kernel. A *kernel* turns the lanes' camera rays into named per-lane values
(radiance, mask, ...); :func:`run_passes` sums them and their squares per pixel, so every
layer comes with the standard error of its mean.

**Samplers and replicas.** Given ``sampler`` (``"independent"``, ``"sobol"`` or ``"sobol2d"``,
see :mod:`arlight.sampling.stream`) the kernel also receives a
:class:`~arlight.sampling.stream.LaneSampler` whose numbers depend only on (seed, pixel, sample
index, dimension), and with ``sobol`` the camera's pixel and lens samples come from it too.
Sample ``k`` of a pixel belongs to *replica* ``r = k mod R`` as its ``j = k div R``-th sample;
every replica is an independent randomisation (its own scrambling seeds), so with ``R ≥ 2`` the
standard error comes from the spread of the ``R`` replica means (``R − 1`` degrees of freedom,
honest for correlated quasi-Monte Carlo samples) rather than from the per-sample variance
(which assumes independent samples: with low-discrepancy samples it overstates the error).
Within a pass a pixel's lanes are laid out replica-major, so the per-replica sums are block
reductions too.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import generate_rays, rays_from_samples
from arlight.errors import InputError
from arlight.interrupts import shielded, test_point
from arlight.jit import MAX_LANES
from arlight.progress import task
from arlight.sampling.stream import CAMERA_LENS, CAMERA_PIXEL, SAMPLERS, LaneSampler
from arlight.scene.camera import Camera

Kernel = Callable[..., dict[str, mi.Float | mi.Color3f]]
"""kernel(rays, pixel_index, sampler_seed, n_lanes) -> {name: per-lane Float or Color3f};
with a ``sampler``, kernel(rays, pixel_index, sampler_seed, n_lanes, lane_sampler)."""


@dataclass
class PixelMoments:
    """Running per-pixel sums of a sampled quantity ``(H, W, C)`` (float64).

    With ``R ≥ 2`` replicas the per-replica sums stay in Dr.Jit (``replica_sums``: float64,
    laid out pixel, channel, replica) until a result needs them: copying them out after
    every pass cost as much as a fifth of a 640×480 render."""

    total: np.ndarray
    total_sq: np.ndarray
    count: int = 0
    n_replicas: int = 1
    replica_sums: mi.Float64 | None = None

    @property
    def mean(self) -> np.ndarray:
        return self.total / max(self.count, 1)

    @property
    def variance(self) -> np.ndarray:
        """Unbiased per-sample variance."""
        n = self.count
        if n < 2:
            return np.full_like(self.total, np.inf)
        return np.maximum(self.total_sq - self.total * self.total / n, 0.0) / (n - 1)

    @property
    def replicas(self) -> int:
        """Independent replicas behind :attr:`stderr` (1: per-sample variance)."""
        return 1 if self.replica_sums is None else self.n_replicas

    @property
    def replica_total(self) -> np.ndarray | None:
        """``(H, W, R, C)`` sums per replica (None without replicas)."""
        if self.replica_sums is None:
            return None
        h, w, c = self.total.shape
        a = np.array(self.replica_sums, dtype=np.float64).reshape(h, w, c, self.n_replicas)
        return a.transpose(0, 1, 3, 2)

    @property
    def dof(self) -> int:
        """Degrees of freedom of :attr:`stderr`."""
        return (self.replicas if self.replicas > 1 else self.count) - 1

    @property
    def stderr(self) -> np.ndarray:
        """Standard error of the per-pixel mean: from the spread of the replica means when
        there are replicas (``sqrt(Σ (m_r − m)² / (R (R − 1)))``), else from the per-sample
        variance."""
        r = self.replicas
        if r < 2:
            return np.sqrt(self.variance / max(self.count, 1))
        assert self.replica_sums is not None
        # Σ (T_r − T̄)² = Σ d_r² − (Σ d_r)² / R with d_r = T_r − T_0 (shifted: no cancellation
        # for a large mean, exactly 0 for equal replicas), in Dr.Jit over the R-blocks
        x = self.replica_sums
        j = dr.arange(mi.UInt32, dr.width(x))
        d = x - dr.gather(mi.Float64, x, j - j % r)
        ss = dr.block_sum(d * d, r) - dr.square(dr.block_sum(d, r)) / r
        n_r = max(self.count // r, 1)
        ss = np.maximum(np.array(ss, dtype=np.float64), 0.0).reshape(self.total.shape)
        return np.sqrt(ss / (r * (r - 1))) / n_r


@dataclass
class PassResult:
    """Moments of every kernel output plus timing and lane counts."""

    moments: dict[str, PixelMoments] = field(default_factory=dict)
    seconds: float = 0.0
    lanes: int = 0


def _to_image(x, height: int, width: int) -> np.ndarray:
    """Per-pixel Dr.Jit values (Float or 3-vector) -> ``(H, W, C)`` float64."""
    a = np.array(x, dtype=np.float64)
    a = a[:, None] if a.ndim == 1 else a.T  # Dr.Jit 3-vectors convert channel-major (3, N)
    return a.reshape(height, width, a.shape[-1])


def _add_replica_sums(mom: PixelMoments, v, n_pix: int, r0: int, g: int, m: int) -> None:
    """Add a pass's per-replica sums of ``v`` (lanes: pixel, then ``g`` replicas from ``r0``
    with ``m`` samples each) into ``mom.replica_sums`` (pixel, channel, replica)."""
    comps = [v] if isinstance(v, mi.Float) else [v.x, v.y, v.z]
    r = mom.n_replicas
    b = dr.arange(mi.UInt32, n_pix * g)
    slot = (b // g) * (len(comps) * r) + (b % g + r0)
    for ci, comp in enumerate(comps):
        # every slot once per pass: plain atomic adds, no SIMD pre-reduction (~2x faster)
        dr.scatter_reduce(dr.ReduceOp.Add, mom.replica_sums,
                          dr.block_sum(mi.Float64(comp), m), slot + ci * r,
                          mode=dr.ReduceMode.Direct)


def effective_replicas(spp: int, replicas: int) -> int:
    """The largest divisor of ``spp`` not above ``replicas`` (replicas hold equal counts)."""
    r = max(1, min(replicas, spp))
    while spp % r:
        r -= 1
    return r


def pass_plan(spp: int, n_rep: int, cap: int) -> list[tuple[int, int, int, int]]:
    """The passes of a render: ``(r0, g, j0, m)`` = replicas ``[r0, r0 + g)``, samples
    ``[j0, j0 + m)`` of each, at most ``max(cap, 1)`` samples per pixel a pass. With
    ``cap ≥ n_rep`` every pass holds all replicas (``m = cap // n_rep`` samples each);
    below, a pass holds ``cap`` replicas one sample each, so a wide image with many replicas
    still keeps a pass within the lane budget. Every (replica, sample) appears once."""
    per_rep = spp // n_rep
    out = []
    if cap >= n_rep:
        step = cap // n_rep
        for j0 in range(0, per_rep, step):
            out.append((0, n_rep, j0, min(step, per_rep - j0)))
    else:
        g = max(1, cap)
        for j0 in range(per_rep):
            for r0 in range(0, n_rep, g):
                out.append((r0, min(g, n_rep - r0), j0, 1))
    return out


def run_passes(camera: Camera, spp: int, kernel: Kernel, seed: int = 0,
               spp_per_pass: int | None = None, progress: str | None = None,
               max_lanes: int = MAX_LANES, sampler: str | None = None,
               replicas: int = 1, scramble_replicas: bool = True,
               sample_offset: int = 0) -> PassResult:
    """Evaluate ``kernel`` on ``spp`` camera samples per pixel and accumulate moments.

    Args:
        camera: the camera whose rays are traced.
        spp: samples per pixel in total (stratified when a perfect square).
        kernel: per-lane estimator (see :data:`Kernel`).
        seed: master seed; the same seed gives bitwise identical results.
        spp_per_pass: samples per pass (default: as many as fit in ``max_lanes``).
        progress: label for a progress bar (None: silent).
        sampler: None (the kernel draws its own numbers from the pass seed), or
            ``"independent"`` / ``"sobol"`` / ``"sobol2d"``: the kernel gets a per-lane
            sampler as a fifth argument (see the module docstring).
        replicas: independent randomisations the standard errors come from (the largest
            divisor of ``spp`` not above it is used; 1: per-sample variance).
        scramble_replicas: True: every replica is its own randomisation (unbiased standard
            errors); False (``sobol``): the replicas are the ``R`` consecutive blocks of one
            scrambled sequence of ``spp`` points per pixel — the whole pixel is one net (the
            lower error of a single sequence), and the spread of the block means gives a
            conservative standard error (blocks of one net are negatively correlated).
        sample_offset: with a ``sampler``, the render draws samples ``[sample_offset,
            sample_offset + spp)`` of every pixel's sequences (a multiple of the replicas):
            renders with the same seed and consecutive offsets continue one low-discrepancy
            sequence (progressive refinement), their mean is a render of all their samples.
    """
    if sampler is not None and sampler not in SAMPLERS:
        raise InputError(f"unknown sampler {sampler!r} (expected one of {SAMPLERS})",
                         field="sampler")
    if replicas < 1:
        raise InputError(f"must be >= 1, got {replicas}", field="replicas")
    w, h = camera.width, camera.height
    n_pix = w * h
    n_rep = effective_replicas(spp, replicas)
    cap = spp_per_pass or max(1, min(spp, max_lanes // n_pix))  # samples per pixel a pass
    if sample_offset < 0 or sample_offset % n_rep:
        raise InputError(f"must be >= 0 and a multiple of the {n_rep} replicas, got "
                         f"{sample_offset}", field="sample_offset")
    offset_u = dr.opaque(mi.UInt32, sample_offset)
    # the multi-jittered camera of `independent` stratifies spp samples: other offsets
    # (other frames) get other patterns through the seed
    cmj_seed = (seed ^ (sample_offset * 0x2C1B3C6D)) & 0xFFFFFFFF
    result = PassResult()
    start = time.perf_counter()
    bar = task(progress or "render", spp, enabled=progress is not None)
    try:
        k0 = 0  # samples per pixel done so far
        for r0, g, j0, m in pass_plan(spp, n_rep, cap):
            n = g * m  # this pass: replicas [r0, r0 + g), samples [j0, j0 + m) of each
            lanes = n * n_pix
            idx = dr.arange(mi.UInt32, lanes)
            # opaque, not literals: one compiled kernel serves every spp and pass plan
            n_u, m_u, rep_u = (dr.opaque(mi.UInt32, x) for x in (n, m, n_rep))
            pixel = idx // n_u
            t = idx % n_u  # replica-major within the pixel
            replica = t // m_u + dr.opaque(mi.UInt32, r0)
            j = t % m_u + dr.opaque(mi.UInt32, j0)  # sample index within the replica
            k = j * rep_u + replica  # sample index within the pixel
            seed_u = dr.opaque(mi.UInt32, seed)
            cmj_u = dr.opaque(mi.UInt32, cmj_seed)
            pass_seed = dr.opaque(mi.UInt32, (seed * 0x9E3779B1 + k0 * 0x85EBCA77) & 0xFFFFFFFF)
            if sampler is None:
                rays = generate_rays(camera, pixel, k, spp, cmj_u)
                outputs = kernel(rays, pixel, pass_seed, lanes)
            else:
                if scramble_replicas:  # sample offset/R + j of replica r's own sequence
                    stream = LaneSampler.for_samples(sampler, pixel, replica,
                                                     j + offset_u // rep_u, seed_u)
                else:  # block r of one sequence: index offset + r·spp/R + j
                    block = dr.opaque(mi.UInt32, spp // n_rep)
                    stream = LaneSampler.for_samples(sampler, pixel, mi.UInt32(0),
                                                     offset_u + replica * block + j, seed_u)
                if sampler != "independent":
                    lens = stream.next_2d(CAMERA_LENS) if camera.aperture_radius > 0 else None
                    rays = rays_from_samples(camera, pixel,
                                             stream.next_2d_of_4d(CAMERA_PIXEL, 0), lens)
                else:
                    rays = generate_rays(camera, pixel, k, spp, cmj_u)
                outputs = kernel(rays, pixel, pass_seed, lanes, stream)
            test_point("kernel")
            with shielded():  # a Ctrl-C waits for the kernel (see arlight.interrupts)
                dr.eval(outputs)  # one render kernel; the reductions below read its results
            sums = {name: (dr.block_sum(v, n), dr.block_sum(v * v, n))
                    for name, v in outputs.items()}
            for name, (total, _) in sums.items():
                mom = result.moments.get(name)
                if mom is None:
                    shape = (h, w, 1 if isinstance(total, mi.Float) else 3)
                    mom = result.moments[name] = PixelMoments(np.zeros(shape), np.zeros(shape),
                                                              n_replicas=n_rep)
                    if n_rep > 1:
                        mom.replica_sums = dr.zeros(mi.Float64, n_pix * shape[2] * n_rep)
                if n_rep > 1:
                    _add_replica_sums(mom, outputs[name], n_pix, r0, g, m)
            dr.eval(sums, [mom.replica_sums for mom in result.moments.values()])
            for name, (total, total_sq) in sums.items():
                mom = result.moments[name]
                mom.total += _to_image(total, h, w)
                mom.total_sq += _to_image(total_sq, h, w)
                mom.count += n
            result.lanes += lanes
            k0 += n
            bar.advance(n)
    finally:
        bar.close()
    result.seconds = time.perf_counter() - start
    return result
