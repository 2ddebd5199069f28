"""Adaptive resolution's pure logic (arlight.studio.adaptive): the scale ladder, the
controller against a render-time model (no clock: times are injected), rest, upsampling."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.layers import upsample
from arlight.studio.adaptive import ScaleController, at_rest, drag_factors, until_rest

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


class _Counting:
    """A method whose spec scales ``size`` (a preparation option) and ``taps`` (a frame
    option) on drag frames; counts its preparations."""

    def __init__(self, floor: int) -> None:
        from arlight.methods.spec import Field, MethodSpec

        self.prepared: list[dict] = []
        self.spec = MethodSpec(
            "counting", "test", {"size": Field("int", 64, "", min=1, max=1024),
                                 "taps": Field("int", 8, "", min=1, max=64)},
            frame_options=frozenset({"taps"}),
            drag_options=lambda o, k: {"size": max(floor, o.size // k), "taps": o.taps // k})

    def prepare(self, world, settings):
        self.prepared.append(self.spec.parse_options(settings.options))
        return ("state", dict(settings.options))


def test_drag_states_prepare_once_per_distinct_preparation_options():
    """With a floor reached at factor 4, factors 4 and 8 share one drag state, factor 2 has
    its own, and each factor renders with its own frame options; factor 1 is the full
    state. Rejects a studio that prepares a state per factor, shares one across different
    preparation options, or drops the frame options of a drag frame."""
    from arlight.methods import RenderSettings
    from arlight.studio.engine import DragStates

    fn = _Counting(floor=16)
    base = RenderSettings()
    full = fn.prepare(None, base)
    drag = DragStates.prepare(fn, None, full, base, (1, 2, 4, 8))
    assert [p["size"] for p in fn.prepared] == [64, 32, 16]
    assert drag.state(1) is full and drag.settings(1) is base
    assert drag.state(4) is drag.state(8) is not drag.state(2)
    assert [drag.settings(k).options["taps"] for k in (2, 4, 8)] == [4, 2, 1]


def test_drag_options_out_of_range_are_refused():
    """A spec whose drag ladder leaves an option's range fails loudly (InputError naming
    the option) instead of rendering drag frames with an invalid option. Rejects a
    ``MethodSpec.drag`` that does not validate."""
    from arlight.errors import InputError

    spec = _Counting(floor=0).spec
    with pytest.raises(InputError, match="size"):
        spec.drag(spec.parse_options({"size": 64}), 128)  # 64 // 128 = 0 < min 1


@pytest.mark.parametrize("method", ["dir", "dlpv", "dvct"])
def test_methods_drag_ladders_are_valid_and_coarser(method):
    """The drag options dir, dlpv and dvct declare are valid options at every factor of a
    640×480 studio and never finer than the full-size ones (dvct's volume stays a power of
    two). Rejects a ladder that refines while dragging or breaks a cross-option check."""
    from arlight.methods import get_method

    spec = get_method(method).spec
    opts = spec.parse_options({})
    for k in drag_factors(640, 480)[1:]:
        extra = spec.drag(opts, k)
        assert extra and all(extra[name] <= opts[name] for name in extra)
        if method == "dvct":
            n = extra["volume_size"]
            assert n & (n - 1) == 0
