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
