import numpy as np
import pytest

from arlight.layers import composite

rng = np.random.default_rng(3)


def test_zero_delta_and_mask_returns_background_bitwise():
    bg = rng.random((8, 9, 3)).astype(np.float32)
    mixed = np.full_like(bg, np.inf)  # whatever mixed holds, it must not leak in
    out = composite(bg, mixed, np.zeros_like(bg), np.zeros((8, 9), np.float32))
    assert np.array_equal(out, bg)


def test_full_mask_returns_mixed_and_formula_elsewhere():
    bg, mixed, delta = (rng.random((4, 5, 3)) for _ in range(3))
    mask = rng.random((4, 5))
    mask[0, 0], mask[1, 1] = 1.0, 0.0
    out = composite(bg, mixed, delta, mask)
    assert np.array_equal(out[0, 0], mixed[0, 0])
    m = mask[..., None]
    assert np.allclose(out, m * mixed + (1 - m) * (bg + delta))


def test_shape_mismatch_raises():
    a = np.zeros((2, 2, 3))
    with pytest.raises(ValueError):
        composite(a, np.zeros((2, 3, 3)), a, np.zeros((2, 2)))


def test_upsampled_layers_are_opencv_bilinear_composited_over_the_full_frame():
    """Layers rendered at half size, upsampled: mixed, delta and mask equal OpenCV's bilinear
    resize (an independent implementation with the same pixel-centre alignment and clamped
    edges), the composite is formed over the *full-size* frame, and where the small render
    changed nothing the full frame comes back bitwise. Rejects corner-aligned or
    nearest-neighbour upsampling, and compositing over an upsampled small frame (which blurs
    the photograph everywhere)."""
    import cv2

    from arlight.layers import Layers

    big = rng.random((12, 16, 3)).astype(np.float32)
    small_bg = big.reshape(6, 2, 8, 2, 3).mean(axis=(1, 3)).astype(np.float32)
    mixed = rng.random((6, 8, 3)).astype(np.float32)
    delta = np.zeros((6, 8, 3), np.float32)
    delta[2:4, 3:6] = -0.2
    mask = np.zeros((6, 8), np.float32)
    mask[1:3, 1:3] = 1.0
    up = Layers.assemble(small_bg, mixed, delta, mask).upsampled(big)
    ref = {k: cv2.resize(v, (16, 12), interpolation=cv2.INTER_LINEAR)
           for k, v in (("mixed", mixed), ("delta", delta), ("mask", mask))}
    for k, v in ref.items():
        assert np.allclose(getattr(up, k), v, atol=1e-6), k
    assert up.background is big
    assert np.array_equal(up.composite, composite(big, up.mixed, up.delta, up.mask))
    untouched = (up.mask == 0) & np.all(up.delta == 0, axis=2)
    assert untouched.sum() > 50 and np.array_equal(up.composite[untouched], big[untouched])
