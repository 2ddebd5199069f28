"""Adaptive resolution's pure logic (arlight.studio.adaptive): the scale ladder, the
controller against a render-time model (no clock: times are injected), rest, upsampling."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.studio.adaptive import ScaleController, at_rest, drag_factors, until_rest, upsample

LADDER = (1, 2, 4, 8)


def model(fixed: float, full: float):
    """Render time of a frame at factor k, seconds: a fixed cost plus a per-pixel one."""
    return lambda k: fixed + full / k**2


def run(ctl: ScaleController, time_of, frames: int) -> list[int]:
    """Drive ``ctl`` for ``frames`` drag frames; the factors it chose."""
    out = []
    for _ in range(frames):
        k = ctl.choose()
        ctl.observe(k, time_of(k))
        out.append(k)
    return out


def test_ladder_is_the_powers_of_two_that_divide_down_to_60_px():
    assert drag_factors(640, 480) == (1, 2, 4, 8)
    assert drag_factors(160, 120) == (1, 2)
    assert drag_factors(641, 480) == (1,)
    assert drag_factors(648, 486) == (1, 2)  # 486/4 is not an integer


def test_never_chooses_a_scale_predicted_above_the_budget_when_one_fits():
    """Rejects a controller that keeps full size (or any scale) over budget: from a slow
    full-size frame it goes down to the finest scale that fits, and stays there."""
    ctl = ScaleController(LADDER, budget_s=0.100)
    ctl.observe(1, 0.400)  # the first (full-size) frame
    t = model(0.010, 0.390)  # k=2: 0.1075 (over), k=4: 0.034
    chosen = run(ctl, t, 20)
    assert all(t(k) <= 0.100 for k in chosen[1:]), chosen
    assert chosen[-1] == 4  # and not coarser than needed


def test_prefers_the_finest_scale_within_budget():
    """Rejects a controller that always drops to the coarsest scale."""
    ctl = ScaleController(LADDER, budget_s=0.100)
    ctl.observe(1, 0.300)
    assert run(ctl, model(0.0, 0.300), 10)[-1] == 2  # 0.075 fits, 1 does not


def test_settles_instead_of_oscillating_around_the_budget():
    """Rejects a controller without memory or hysteresis: full size is just over the
    budget (0.110 s) and half size well under (0.080 s); a controller that steps up
    whenever the current scale fits would alternate 1, 2, 1, 2, ..."""
    ctl = ScaleController(LADDER, budget_s=0.100)
    chosen = run(ctl, model(0.070, 0.040), 60)  # k=1: 0.110, k=2: 0.080
    changes = sum(a != b for a, b in zip(chosen, chosen[1:], strict=False))
    assert chosen[-1] == 2 and changes <= 2, chosen


def test_goes_back_to_full_size_when_the_load_drops():
    """Rejects a controller that never goes back up: after a heavy phase at a coarse scale
    the machine gets 16× faster; within ``memory`` frames it renders full size again, and
    never above budget meanwhile."""
    ctl = ScaleController(LADDER, budget_s=0.100, memory=24)
    ctl.observe(1, 0.800)
    run(ctl, model(0.0, 0.800), 10)
    assert ctl.current == 4
    fast = model(0.0, 0.050)
    chosen = run(ctl, fast, 24 + 2)
    assert chosen[-1] == 1 and all(fast(k) <= 0.100 for k in chosen), chosen


def test_cheap_still_frames_do_not_pull_the_drag_to_full_size():
    """Rejects a controller fed with the frames at rest as if they were drag frames: a
    still full-size frame (no pose) takes 0.060 s, a moving one 0.230 s; after the first
    drag, still frames between drags must not make the next drag start at full size."""
    ctl = ScaleController(LADDER, budget_s=0.100)
    ctl.seed(1, 0.060)  # the first frame, at rest: all that is known
    moving = model(0.0, 0.230)
    first = run(ctl, moving, 6)
    assert first[0] == 1 and first[-1] == 2  # one slow frame, then within budget
    for _ in range(3):
        ctl.seed(1, 0.060)  # full-size frames at rest between drags
        assert run(ctl, moving, 3) == [2, 2, 2]


def test_forgets_measurements_of_scales_not_rendered_for_a_long_time():
    """Rejects a controller that trusts a stale full-size time forever: an old slow
    measurement at k=1 stops blocking once k=4 frames show the machine got faster."""
    ctl = ScaleController(LADDER, budget_s=0.100, memory=8)
    ctl.observe(1, 1.0)
    ctl.observe(2, 0.5)
    chosen = run(ctl, model(0.0, 0.040), 30)  # now everything is fast
    assert chosen[-1] == 1, chosen


def test_nothing_fits_gives_the_coarsest_and_nothing_measured_stays():
    ctl = ScaleController(LADDER, budget_s=0.100)
    assert ctl.choose() == 1  # nothing measured yet: stay at the current (full) size
    ctl.observe(1, 5.0)
    assert run(ctl, model(0.5, 4.5), 5)[-1] == 8  # fixed cost over budget everywhere


@pytest.mark.parametrize("bad", [dict(factors=()), dict(factors=(2, 4)),
                                 dict(factors=(1, 4, 2)), dict(factors=LADDER, budget_s=0),
                                 dict(factors=LADDER, up_margin=1.5)])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        ScaleController(**bad)


def test_rest_is_judged_on_the_injected_clock():
    """Rejects a rest test that never becomes true (no refinement) or is true while
    motion messages keep coming (no adaptivity)."""
    assert at_rest(10.0, None, 0.15)
    assert not at_rest(10.1, 10.0, 0.15)
    assert at_rest(10.15, 10.0, 0.15)
    assert until_rest(10.1, 10.0, 0.15) == pytest.approx(0.05)
    assert until_rest(11.0, 10.0, 0.15) == 0.0


def test_upsample_keeps_constants_and_puts_block_centres_back():
    rng = np.random.default_rng(0)
    const = np.full((3, 4, 3), 0.25, np.float32)
    assert np.array_equal(upsample(const, 12, 16), np.full((12, 16, 3), 0.25, np.float32))
    small = rng.random((6, 8)).astype(np.float32)
    big = upsample(small, 24, 32)
    assert big.shape == (24, 32) and big.dtype == np.float32
    # a linear ramp over the small image's pixel centres is reproduced exactly at the big
    # image's pixel centres (away from the clamped border); rejects a half-pixel shift
    y, x = np.mgrid[0:6, 0:8].astype(np.float32)
    ramp = upsample(0.5 * x + 0.25 * y, 24, 32)
    yb, xb = np.mgrid[0:24, 0:32].astype(np.float32)
    want = 0.5 * ((xb + 0.5) / 4 - 0.5) + 0.25 * ((yb + 0.5) / 4 - 0.5)
    assert np.allclose(ramp[2:-2, 2:-2], want[2:-2, 2:-2], atol=1e-5)
    assert big.min() >= small.min() - 1e-6 and big.max() <= small.max() + 1e-6
    assert np.array_equal(upsample(small, 6, 8), small)
