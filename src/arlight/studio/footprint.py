"""A drag frame at full size from the insertion's footprint only (issue #32).

A studio frame rendered at 1/k of the size while the pointer drags is shown at full size:
its ``mixed``, ``delta`` and ``mask`` are upsampled bilinearly and composited over the
full-size photo (:meth:`arlight.layers.Layers.upsampled`), and the composite goes through
the camera transfer for display (:func:`arlight.studio.imaging.display`). Outside the
insertion's *footprint* — the small render's pixels where the virtual object covers
(``mask > 0``) or the real scene changes (``delta ≠ 0``: its shadow, its bounce) — the
composite is the photo bit for bit (:func:`arlight.layers.composite`: ``M = 0`` and
``Δ = 0``), and so are its display codes. :func:`footprint_window` finds the full-size
window whose bilinear taps read the footprint's bounding box; only that window is
upsampled and composited (:func:`composite_window`) and only its display codes computed
over the photo's, which are computed once per exposure (:class:`PhotoCodes`).

The other layers (``mixed``, ``delta``, ``mask``) are upsampled in full only when shown
(:class:`DragImages`).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from arlight.layers import Layers, composite, touching, upsample

Window = tuple[slice, slice]
"""Full-size ``(rows, cols)`` of a frame, slices with step 1."""


def footprint(layers: Layers) -> np.ndarray:
    """``(h, w)`` bool: the pixels of ``layers`` where the insertion shows — the virtual
    object covers them (``mask > 0``) or the real scene changes (any ``delta`` channel
    ≠ 0)."""
    return (np.asarray(layers.mask) > 0) | np.any(np.asarray(layers.delta) != 0, axis=-1)


def footprint_window(small: np.ndarray, height: int, width: int) -> Window:
    """The full-size ``(height, width)`` window whose bilinear taps (:func:`arlight.layers.
    upsample`) read any pixel of the bounding box of the ``(h, w)`` footprint ``small``
    (:func:`footprint`); empty slices when the footprint is empty. Outside it every
    upsampled ``delta`` and ``mask`` pixel is exactly 0."""
    rows, cols = np.flatnonzero(small.any(axis=1)), np.flatnonzero(small.any(axis=0))
    if not rows.size:
        return slice(0, 0), slice(0, 0)
    h, w = small.shape
    return (touching(height, h, int(rows[0]), int(rows[-1])),
            touching(width, w, int(cols[0]), int(cols[-1])))


def composite_window(layers: Layers, background: np.ndarray, window: Window) -> np.ndarray:
    """The full-size composite of ``layers`` (rendered smaller) over ``background``:
    ``background`` outside ``window``, inside it the window of
    ``layers.upsampled(background).composite`` — computed from that window only (``mixed``
    from the smaller window of ``mask > 0``: the composite reads it where the object
    covers only), bit for bit the same (float32, ``(H, W, 3)``)."""
    h, w = background.shape[:2]
    out = np.array(background, np.float32, copy=True)
    rows, cols = window
    if rows.stop > rows.start and cols.stop > cols.start:
        delta, mask = (upsample(a, h, w, rows, cols) for a in (layers.delta, layers.mask))
        # mixed is read where the mask covers only: upsampled in the mask's window
        mixed = np.zeros(delta.shape, np.float32)
        mr, mc = footprint_window(np.asarray(layers.mask) > 0, h, w)
        if mr.stop > mr.start and mc.stop > mc.start:
            mixed[mr.start - rows.start:mr.stop - rows.start,
                  mc.start - cols.start:mc.stop - cols.start] = upsample(layers.mixed, h, w,
                                                                          mr, mc)
        out[rows, cols] = composite(background[rows, cols], mixed, delta, mask)
    return out


class DragImages(Mapping):
    """The full-size layers of a drag frame as the studio keeps them (``composite``,
    ``mixed``, ``delta``, ``mask``): the composite from the footprint's window
    (:func:`composite_window`), the others upsampled in full on first use (a layer the page
    does not show costs nothing)."""

    def __init__(self, layers: Layers, background: np.ndarray, window: Window) -> None:
        self.small = layers
        self.background = background
        self.window = window
        self._full: dict[str, np.ndarray] = {
            "composite": composite_window(layers, background, window)}

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in self._full:
            if key not in ("mixed", "delta", "mask"):
                raise KeyError(key)
            h, w = self.background.shape[:2]
            self._full[key] = upsample(getattr(self.small, key), h, w)
        return self._full[key]

    def __iter__(self) -> Iterator[str]:
        return iter(("composite", "mixed", "delta", "mask"))

    def __len__(self) -> int:
        return 4


@dataclass
class PhotoCodes:
    """Display codes of the full-size photo per exposure offset (the composite of a frame
    with nothing inserted), kept for the frames whose footprint is smaller than the frame.

    Attributes:
        photo: the full-size photo (linear radiance, ``(H, W, 3)``).
    """

    photo: np.ndarray
    _codes: dict[tuple[float, object], np.ndarray] | None = None

    def codes(self, transfer, ev: float) -> np.ndarray:
        """``imaging.display("composite", …)`` of the photo at ``ev`` (read-only)."""
        from arlight.studio import imaging

        key = (float(ev), transfer)
        if self._codes is None:
            self._codes = {}
        if key not in self._codes:
            if len(self._codes) > 8:
                self._codes.clear()
            c = imaging.display("composite", {"composite": self.photo}, transfer, ev, None)
            c.setflags(write=False)
            self._codes[key] = c
        return self._codes[key]

    def display(self, images: Mapping[str, np.ndarray], window: Window, transfer,
                ev: float) -> np.ndarray:
        """The display codes of ``images["composite"]`` that equals the photo outside
        ``window``: the photo's codes with the window's computed (``(H, W, 3)`` uint8, bit
        for bit ``imaging.display("composite", images, …)``)."""
        from arlight.studio import imaging

        out = self.codes(transfer, ev).copy()
        rows, cols = window
        if rows.stop > rows.start and cols.stop > cols.start:
            out[rows, cols] = imaging.display(
                "composite", {"composite": images["composite"][rows, cols]}, transfer, ev,
                None)
        return out


__all__ = ["DragImages", "PhotoCodes", "Window", "composite_window", "footprint",
           "footprint_window"]
