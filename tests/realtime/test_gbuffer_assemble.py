"""Per-pixel layers from per-sample shading (:func:`arlight.realtime.gbuffer.assemble`).

The reference is written from the definition, sample by sample, in plain NumPy loops: a
virtual sample shows its ``mixed`` radiance, any other sample the photograph changed by its
``delta − hidden · B``; the pixel's composite is the mean over its samples. The fast path
(strided lane sums, the change divided by the non-virtual count) must give the same."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.mitsuba_scene import ROLE_MISS, ROLE_REAL, ROLE_VIRTUAL
from arlight.realtime.gbuffer import GBuffer, assemble, lane_sum, resolve, resolve_scalar


def _gbuffer(role: np.ndarray, spp: int, width: int, height: int) -> GBuffer:
    n = role.size
    z = mi.Float(np.zeros(n, np.float32))
    p = mi.Point3f(z, z, z)
    return GBuffer(p, mi.Vector3f(p), mi.Color3f(z, z, z), mi.Int32(role.astype(np.int32)),
                   z, mi.UInt32(np.arange(n, dtype=np.uint32) // spp), mi.Vector3f(p), spp,
                   width, height)


def _color(a: np.ndarray) -> mi.Color3f:
    return mi.Color3f(*(mi.Float(np.ascontiguousarray(a[:, c])) for c in range(3)))


def _reference(role, frame, mixed, delta, hidden, spp):
    """The mean over each pixel's samples of the per-sample composite, loop by loop."""
    h, w = frame.shape[:2]
    out = np.zeros((h, w, 3))
    for pix in range(h * w):
        b = frame.reshape(-1, 3)[pix].astype(np.float64)
        acc = np.zeros(3)
        for k in range(spp):
            lane = pix * spp + k
            if role[lane] == ROLE_VIRTUAL:
                acc += mixed[lane]
            else:
                acc += b + delta[lane] - hidden[lane] * b
        out.reshape(-1, 3)[pix] = acc / spp
    return out


@pytest.mark.parametrize("spp", [1, 3, 4])
def test_composite_is_the_mean_of_the_sample_composites(spp):
    """Rejects: ``hidden`` ignored, or divided by ``spp`` instead of the pixel's count of
    non-virtual samples; the change averaged over all samples (virtual ones diluting it);
    a lane sum that skips or repeats a sample plane."""
    rng = np.random.default_rng(7)
    width, height = 5, 4
    n = width * height * spp
    role = rng.choice([ROLE_REAL, ROLE_VIRTUAL, ROLE_MISS], n, p=[0.5, 0.35, 0.15])
    role[:spp] = ROLE_VIRTUAL  # one pixel wholly virtual, one wholly real
    role[spp:2 * spp] = ROLE_REAL
    frame = rng.uniform(0.1, 2.0, (height, width, 3)).astype(np.float32)
    virtual = (role == ROLE_VIRTUAL)[:, None]  # the shaders' lanes: mixed on virtual ones,
    # delta and hidden on the others (zero elsewhere)
    mixed = np.where(virtual, rng.uniform(0.0, 3.0, (n, 3)), 0.0).astype(np.float32)
    delta = np.where(virtual, 0.0, rng.uniform(-0.5, 0.5, (n, 3))).astype(np.float32)
    hidden = np.where(virtual[:, 0], 0.0, rng.uniform(0.0, 0.6, n)).astype(np.float32)
    gb = _gbuffer(role, spp, width, height)
    layers = assemble(gb, frame, _color(mixed), _color(delta), {}, mi.Float(hidden))
    want = _reference(role, frame, mixed, delta, hidden, spp)
    np.testing.assert_allclose(layers.composite, want, rtol=2e-6, atol=2e-6)
    np.testing.assert_allclose(layers.mask, (role == ROLE_VIRTUAL).reshape(-1, spp).mean(1)
                               .reshape(height, width), atol=1e-7)


def test_resolve_matches_a_plain_mean():
    """Rejects a lane sum reshaped the wrong way round (pixels × samples swapped)."""
    rng = np.random.default_rng(3)
    width, height, spp = 6, 2, 4
    vals = rng.normal(size=(width * height * spp, 3)).astype(np.float32)
    gb = _gbuffer(np.zeros(len(vals), int), spp, width, height)
    want = vals.astype(np.float64).reshape(height, width, spp, 3).mean(axis=2)
    np.testing.assert_allclose(resolve(gb, _color(vals)), want, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(resolve_scalar(gb, mi.Float(vals[:, 0])), want[..., 0],
                               rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(lane_sum(gb, np.arange(8 * 6, dtype=np.float32))[:2],
                                  [0 + 1 + 2 + 3, 4 + 5 + 6 + 7])
