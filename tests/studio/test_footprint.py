"""A drag frame composited and displayed in the insertion's footprint only (issue #32,
:mod:`arlight.studio.footprint`): bit for bit the whole frame upsampled, composited and
displayed, with the photo's pixels and codes untouched outside the footprint."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.camera_response import Transfer
from arlight.layers import Layers, upsample
from arlight.studio import imaging
from arlight.studio.footprint import (
    DragImages,
    PhotoCodes,
    composite_window,
    footprint,
    footprint_window,
)

H, W, K = 96, 128, 8  # full size and downscale factor


def _small_layers(rng: np.random.Generator, rows: slice, cols: slice) -> Layers:
    """A small render whose object covers a block and whose delta (shadow and bounce)
    reaches a larger block around it; zero (and -0.0 in places) elsewhere."""
    h, w = H // K, W // K
    bg = rng.uniform(0.0, 2.0, (h, w, 3)).astype(np.float32)
    mixed = rng.uniform(0.0, 3.0, (h, w, 3)).astype(np.float32)  # nonzero everywhere (dlpv)
    delta = np.zeros((h, w, 3), np.float32)
    delta[rows, cols] = rng.uniform(-0.5, 0.2, delta[rows, cols].shape)
    delta[0, 0] = -0.0
    mask = np.zeros((h, w), np.float32)
    r, c = slice(rows.start + 1, rows.stop - 1), slice(cols.start + 1, cols.stop - 1)
    mask[r, c] = rng.uniform(0.2, 1.0, mask[r, c].shape)
    comp = bg + delta
    return Layers(bg, mixed, delta, mask, comp)


@pytest.mark.parametrize("rows, cols", [(slice(3, 7), slice(5, 9)), (slice(0, 4), slice(0, 3)),
                                        (slice(8, 12), slice(12, 16)),
                                        (slice(0, 12), slice(0, 16))])
def test_footprint_composite_is_the_whole_frame_bit_for_bit(rows, cols):
    """Rejects a window that is the footprint's box scaled by the factor without the reach
    of the bilinear taps (the half pixel around it keeps the photo where the whole frame
    has the shadow's edge), window upsampling with the window's own taps instead of the
    frame's (a shifted ramp), a composite that is not the photo outside, or one computed
    in float64 from the photo (other bits)."""
    rng = np.random.default_rng(3)
    small = _small_layers(rng, rows, cols)
    photo = rng.uniform(0.0, 2.0, (H, W, 3)).astype(np.float32)
    whole = small.upsampled(photo)
    window = footprint_window(footprint(small), H, W)
    got = composite_window(small, photo, window)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, whole.composite)
    outside = np.ones((H, W), bool)
    outside[window] = False
    assert outside.any() or (rows, cols) == (slice(0, 12), slice(0, 16))
    np.testing.assert_array_equal(got[outside], photo[outside])
    # the window is no larger than the taps require: its border rows/cols differ from the photo
    r, c = window
    assert np.any(whole.composite[r.start] != photo[r.start])
    assert np.any(whole.composite[r.stop - 1] != photo[r.stop - 1])
    assert np.any(whole.composite[:, c.start] != photo[:, c.start])
    assert np.any(whole.composite[:, c.stop - 1] != photo[:, c.stop - 1])


def test_window_upsampling_equals_the_window_of_the_whole():
    """Rejects taps recomputed for the window's size or offset by its start."""
    rng = np.random.default_rng(5)
    img = rng.normal(size=(12, 16, 3)).astype(np.float32)
    full = upsample(img, H, W)
    for rows, cols in ((slice(0, H), slice(0, W)), (slice(13, 40), slice(7, 101)),
                       (slice(95, 96), slice(0, 1))):
        np.testing.assert_array_equal(upsample(img, H, W, rows, cols), full[rows, cols])


def test_nothing_inserted_leaves_the_photo():
    """An empty footprint (the object outside the view) shows the photo's own codes."""
    rng = np.random.default_rng(7)
    small = _small_layers(rng, slice(3, 7), slice(5, 9))
    small = Layers(small.background, small.mixed, np.zeros_like(small.delta),
                   np.zeros_like(small.mask), small.background)
    photo = rng.uniform(0.0, 2.0, (H, W, 3)).astype(np.float32)
    window = footprint_window(footprint(small), H, W)
    assert window == (slice(0, 0), slice(0, 0))
    np.testing.assert_array_equal(composite_window(small, photo, window), photo)
    tr = Transfer()
    codes = PhotoCodes(photo).display(DragImages(small, photo, window), window, tr, 0.0)
    np.testing.assert_array_equal(codes, tr.to_display(photo))


def test_display_codes_and_other_layers_are_the_whole_frames():
    """Rejects the photo's codes cached across exposures, a window whose codes are not
    computed again, and ``mixed``/``delta``/``mask`` layers that are not the whole frame
    upsampled."""
    rng = np.random.default_rng(11)
    small = _small_layers(rng, slice(2, 8), slice(4, 11))
    photo = rng.uniform(0.0, 2.0, (H, W, 3)).astype(np.float32)
    whole = small.upsampled(photo)
    window = footprint_window(footprint(small), H, W)
    images = DragImages(small, photo, window)
    cache = PhotoCodes(photo)
    tr = Transfer(exposure=0.5)
    for ev in (0.0, -1.5, 0.0, 2.0):
        want = imaging.display("composite", {"composite": whole.composite}, tr, ev, None)
        np.testing.assert_array_equal(cache.display(images, window, tr, ev), want)
    for name in ("mixed", "delta", "mask"):
        np.testing.assert_array_equal(images[name], getattr(whole, name))
        want = imaging.display(name, {name: getattr(whole, name)}, tr, 0.3, None)
        np.testing.assert_array_equal(imaging.display(name, images, tr, 0.3, None), want)
    assert sorted(images) == ["composite", "delta", "mask", "mixed"]
