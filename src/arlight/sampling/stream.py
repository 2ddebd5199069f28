"""Per-lane random numbers of a path tracer: ``independent`` hashes or Owen-scrambled Sobol.

A :class:`LaneSampler` hands every lane (one camera sample) its numbers for a flat
*dimension* ``d``: the tracers ask for ``d = depth · dims_per_depth + slot`` (light sample,
BSDF lobe, BSDF direction, Russian roulette), the camera for its pixel and lens dimensions.
Numbers depend only on (seed, pixel, sample index, dimension), never on the pass or the lane
that draws them, so a pixel's samples may be drawn in any passes in any order, and a path
retraced in another view at the same depth (the one-pass tracer's phase 2) reads the same
numbers.

* ``independent``: TEA hashes of a per-sample key and ``d`` (uniform, independent).
* ``sobol``: sample ``j`` of replica ``r`` of a pixel reads the shuffled, Owen-scrambled
  Sobol sequence (:mod:`arlight.sampling.sobol`) with a seed per (pixel, replica) and one per
  dimension set: each 2D set (pixel, lens, light, BSDF) and 1D set (lobe, roulette) is a
  randomised (0, m, 2)-net over a pixel's first ``2^m`` samples, sets are decorrelated by the
  shuffles, and replicas are independent randomisations (for honest standard errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from arlight.sampling.sobol import hash_combine, sobol_1d, sobol_2d, sobol_4d_half

SAMPLERS = ("sobol", "sobol2d", "independent")
_CAMERA_BASE = 0xC0000000  # dimension ids of the camera's sets (far from path dimensions)
CAMERA_PIXEL, CAMERA_LENS = _CAMERA_BASE, _CAMERA_BASE + 1


def pixel_key(pixel: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """Per-pixel hash of (pixel index, seed) (the camera's multi-jitter key too)."""
    return mi.sample_tea_32(pixel, seed, 4)[0]


@dataclass
class LaneSampler:
    """Random numbers of a wavefront of lanes.

    Attributes:
        kind: ``"independent"`` or ``"sobol"``.
        key: ``independent``: per-sample TEA key; ``sobol``: per-(pixel, replica) seed.
        index: ``sobol``: sample index within the replica (``None`` for ``independent``).
    """

    kind: str
    key: mi.UInt32
    index: mi.UInt32 | None = None

    @staticmethod
    def independent(key: mi.UInt32) -> LaneSampler:
        """TEA-hashed numbers from per-lane keys (e.g. one key per camera sample)."""
        return LaneSampler("independent", mi.UInt32(key))

    @staticmethod
    def for_samples(kind: str, pixel: mi.UInt32, replica: mi.UInt32, index: mi.UInt32,
                    seed: mi.UInt32) -> LaneSampler:
        """The sampler of sample ``index`` of ``replica`` in ``pixel`` (master ``seed``).

        ``independent`` hashes (pixel, replica, index) into one key per sample; ``sobol``
        keeps the index and seeds the scrambles by (pixel, replica).
        """
        base = hash_combine(pixel_key(pixel, seed), replica)
        if kind in ("sobol", "sobol2d"):
            return LaneSampler(kind, base, mi.UInt32(index))
        if kind == "independent":
            return LaneSampler("independent", mi.sample_tea_32(base, index, 4)[0])
        raise ValueError(f"unknown sampler {kind!r} (expected one of {SAMPLERS})")

    def next_1d(self, dim) -> mi.Float:
        """Uniform number in ``[0, 1)`` for dimension ``dim`` (int or per-lane UInt32)."""
        if self.index is None:
            return mi.sample_tea_float32(self.key, dim, 6)
        return sobol_1d(self.index, hash_combine(self.key, dim))

    def next_2d(self, dim) -> mi.Point2f:
        """Uniform point in ``[0, 1)²`` for the 2D set starting at ``dim`` (uses ``dim`` and
        ``dim + 1`` under ``independent``, as two 1D draws)."""
        if self.index is None:
            return mi.Point2f(self.next_1d(dim), self.next_1d(dim + 1))
        return sobol_2d(self.index, hash_combine(self.key, dim))

    @property
    def joint_4d(self) -> bool:
        """Whether paired 2D sets come from one 4D point (``sobol``; not ``sobol2d``)."""
        return self.kind == "sobol"

    def next_2d_of_4d(self, dim, half: int) -> mi.Point2f:
        """Half ``half`` (0: coordinates 0–1, 1: 2–3) of the 4D set ``dim``: two 2D draws
        from one set are jointly stratified under ``sobol``. Under ``independent``: the 2D
        set ``dim + 2·half``."""
        if not self.joint_4d:
            return self.next_2d(dim + 2 * half)
        return sobol_4d_half(self.index, hash_combine(self.key, dim), half)

    def gather(self, idx: mi.UInt32) -> LaneSampler:
        """The sampler of the lanes ``idx`` (after a compaction)."""
        index = None if self.index is None else dr.gather(mi.UInt32, self.index, idx)
        return LaneSampler(self.kind, dr.gather(mi.UInt32, self.key, idx), index)

    def sample_key(self) -> mi.UInt32:
        """One 32-bit key per sample, for code that hashes its own numbers (photon gather)."""
        if self.index is None:
            return self.key
        return hash_combine(self.key, self.index)


__all__ = ["CAMERA_LENS", "CAMERA_PIXEL", "LaneSampler", "SAMPLERS", "pixel_key"]
