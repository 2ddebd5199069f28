"""Adaptive resolution while the pointer drags (issue #32): which scale to render at, and
when the pointer rests — pure logic, no clock and no rendering (the engine feeds it).

* **Scales** are integer downscale factors ``k`` of the studio's size: the frame is
  rendered at ``(W/k) × (H/k)`` (the camera through ``Camera.resized``, the photo and depth
  box-filtered by ``ARScene.resized``) and its layers upsampled back to ``W × H``
  (:func:`arlight.layers.upsample`, bilinear) before compositing over the full-resolution photo. The
  ladder (:func:`drag_factors`) is the powers of two that divide both sides, down to a
  height of :data:`MIN_DRAG_HEIGHT` pixels.
* **Which scale** (:class:`ScaleController`): an exponential moving average of the
  measured render time (seconds) of drag frames per factor (a still frame only seeds it);
  a factor without a recent measurement is predicted from the nearest one measured, in
  proportion to its pixel count. The finest
  factor whose prediction fits the budget is chosen; going *finer* than the current one
  needs the prediction to fit ``up_margin`` × the budget (hysteresis: no flip-flop
  between a scale just over and one just under the budget). When none fits, the coarsest.
* **At rest** (:func:`at_rest`): no motion message for ``rest_s`` seconds; the engine then
  renders once at full resolution (factor 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

MIN_DRAG_HEIGHT = 60
"""Smallest frame height rendered while dragging, pixels (640×480 → at most 1/8)."""
MAX_DRAG_FACTOR = 8
"""Coarsest downscale factor."""


def drag_factors(width: int, height: int, min_height: int = MIN_DRAG_HEIGHT,
                 max_factor: int = MAX_DRAG_FACTOR) -> tuple[int, ...]:
    """The downscale factors available for a ``width × height`` studio, finest first:
    1, 2, 4, ... while both sides divide and the height stays ≥ ``min_height`` px."""
    out = [1]
    k = 2
    while (k <= max_factor and width % k == 0 and height % k == 0
           and height // k >= min_height):
        out.append(k)
        k *= 2
    return tuple(out)


def at_rest(now: float, last_motion: float | None, rest_s: float) -> bool:
    """Whether the pointer rests: no motion message since ``rest_s`` seconds before ``now``
    (both on one monotonic clock, seconds); True when there never was one."""
    return last_motion is None or now - last_motion >= rest_s


def until_rest(now: float, last_motion: float | None, rest_s: float) -> float:
    """Seconds from ``now`` until :func:`at_rest` becomes true (0 when it is)."""
    return 0.0 if last_motion is None else max(0.0, last_motion + rest_s - now)


@dataclass
class ScaleController:
    """Chooses the downscale factor of the next frame rendered while dragging.

    Attributes:
        factors: the factors available, finest (1) first (:func:`drag_factors`).
        budget_s: render budget of a frame while dragging, seconds.
        up_margin: going finer than the current factor needs a prediction within this
            fraction of the budget (hysteresis), dimensionless in (0, 1].
        alpha: weight of a new measurement in the moving average, in (0, 1].
        memory: a factor's average counts as current for this many observations (of any
            factor) after its last one; older ones are ignored (the load changes).
    """

    factors: tuple[int, ...]
    budget_s: float = 0.100
    up_margin: float = 0.7
    alpha: float = 0.5
    memory: int = 24
    current: int = 1
    _mean: dict[int, float] = field(default_factory=dict)
    _seen: dict[int, int] = field(default_factory=dict)
    _count: int = 0
    _seeded: bool = False

    def __post_init__(self) -> None:
        if not self.factors or self.factors[0] != 1 or list(self.factors) != sorted(
                set(self.factors)):
            raise ValueError(f"factors must be increasing from 1, got {self.factors}")
        if not (self.budget_s > 0 and 0 < self.up_margin <= 1 and 0 < self.alpha <= 1):
            raise ValueError("budget_s > 0, 0 < up_margin <= 1 and 0 < alpha <= 1 needed")

    def observe(self, factor: int, seconds: float) -> None:
        """Record the render time (seconds) of a frame rendered at ``factor``."""
        if factor not in self.factors or not math.isfinite(seconds) or seconds < 0:
            return
        if self._seeded:  # the first drag frame replaces the still frame's time
            self._mean, self._seen, self._seeded = {}, {}, False
        self._count += 1
        old = self._fresh().get(factor)
        self._mean[factor] = seconds if old is None else (
            self.alpha * seconds + (1 - self.alpha) * old)
        self._seen[factor] = self._count

    def seed(self, factor: int, seconds: float) -> None:
        """Record the render time (seconds) of a frame that moved nothing (a full-size frame
        at rest, a switch): used only until the first drag frame is measured — a still
        frame skips the pose and would pull the next drag to a size it cannot keep."""
        if not self._mean:
            self.observe(factor, seconds)
            self._seeded = True

    def _fresh(self) -> dict[int, float]:
        return {k: v for k, v in self._mean.items()
                if self._count - self._seen[k] < self.memory}

    def predict(self, factor: int) -> float | None:
        """Predicted render time at ``factor``, seconds (None: nothing measured yet)."""
        fresh = self._fresh()
        if factor in fresh:
            return fresh[factor]
        if not fresh:
            return None
        near = min(fresh, key=lambda k: (abs(math.log(k / factor)), k))
        return fresh[near] * (near / factor) ** 2  # in proportion to the pixel count

    def choose(self) -> int:
        """The factor of the next drag frame (remembered as :attr:`current`)."""
        best = self.factors[-1]
        for k in self.factors:  # finest first
            t = self.predict(k)
            if t is None:  # nothing measured: stay
                best = self.current
                break
            limit = self.budget_s * (self.up_margin if k < self.current else 1.0)
            if t <= limit:
                best = k
                break
        self.current = best
        return best


