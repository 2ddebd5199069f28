"""Distributions over worlds and the equal-time rule (issue #30), against hand-computed
values."""

from __future__ import annotations

import math

import pytest

from arlight.evaluate.distribution import LadderPoint, method_rows, onepass_at, spread
from arlight.evaluate.harness import CellResult


def test_spread_median_tenth_percentile_and_worst():
    """1..10: median 5.5; 10th percentile by linear interpolation at rank 0.9 → 1.9; the
    worst is the minimum (higher is better) or the maximum (lower is better); non-finite
    values are left out (rejects a spread that lets NaN poison the median or that reports
    the best world as the worst)."""
    v = [float(x) for x in range(10, 0, -1)] + [math.nan, math.inf]
    s = spread(v)
    assert (s.n, s.median, s.p10, s.worst) == (10, 5.5, pytest.approx(1.9), 1.0)
    s = spread(v, higher_is_better=False)
    assert (s.median, s.p10, s.worst) == (5.5, pytest.approx(9.1), 10.0)
    assert spread([]).n == 0 and math.isnan(spread([]).median)


def test_onepass_at_never_gives_onepass_more_time():
    """The frame with the most samples among those no slower than the method, even when a
    bigger spp happened to run faster than a smaller one (timing noise); None when every
    frame is slower."""
    ladder = [LadderPoint(1, 0.30, {}), LadderPoint(2, 0.25, {}), LadderPoint(4, 0.50, {})]
    assert onepass_at(ladder, 0.28).spp == 2
    assert onepass_at(ladder, 0.31).spp == 2
    assert onepass_at(ladder, 0.50).spp == 4
    assert onepass_at(ladder, 0.2) is None


def _cell(method, scene, psnr, at=None, spp=1):
    c = CellResult(method=method, scene=scene, seconds=0.1)
    c.metrics = {"psnr": psnr, "changed_psnr": psnr - 3, "flip": 0.1}
    if at is not None:
        c.metrics.update(onepass_at_time_psnr=at, onepass_at_time_changed_psnr=at - 3,
                         onepass_at_time_flip=0.1, onepass_at_time_spp=float(spp))
    return c


def test_method_rows_count_wins_and_deltas_per_class():
    """dlpv: +2 dB on world a, −1 dB on b, and onepass had no frame that fast on c (a win,
    left out of Δ); a skipped cell counts as skipped, not as a world run."""
    cells = [_cell("dlpv", "a", 30, 28, 4), _cell("dlpv", "b", 25, 26, 2),
             _cell("dlpv", "c", 20, math.nan, 0), _cell("onepass", "a", 29)]
    cells.append(CellResult(method="dlpv", scene="d", skipped="glass"))
    rows = method_rows(cells, {"a": "room", "b": "room", "c": "outdoor", "d": "outdoor"})
    dl = next(r for r in rows if r.method == "dlpv" and r.group == "all")
    assert (dl.ran, dl.skipped, dl.wins, dl.compared, dl.no_onepass_frame) == (3, 1, 2, 3, 1)
    assert dl.equal_time_delta.n == 2 and dl.equal_time_delta.median == pytest.approx(0.5)
    assert dl.equal_time_delta.worst == pytest.approx(-1.0)
    room = next(r for r in rows if r.method == "dlpv" and r.group == "room")
    assert (room.ran, room.wins, room.psnr.median) == (2, 1, 27.5)
    one = next(r for r in rows if r.method == "onepass" and r.group == "all")
    assert one.compared == 0 and one.ran == 1
