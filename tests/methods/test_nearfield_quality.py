"""``nearfield`` graded against the suite's Mitsuba ground truth, as dlpv, dir, dvct and dic are
(:func:`tests.methods.test_dlpv.suite_quality`: MSE ratios composite / untouched frame at the
quick size, 64-spp photographs), on the scene Rohmer's method is for: cornell-near-field, a
room whose light all lands on the proxy (measured 0.91 overall, 0.11 virtual, 0.45 ring).
Rejects a black or unlit object, a shadow of the wrong sign or scale, VALs in the wrong place.

Not graded on the environment-lit scenes: the method captures only light that lands on the
proxy, so under an open sky it is worse than the frame (bunny-box 1.14, red-paper 1.13
overall; see docs/methods/nearfield.md, Limitations)."""

from __future__ import annotations

from tests.methods.test_dlpv import suite_quality


def test_quality_against_ground_truth_near_field_room():
    r = suite_quality("nearfield", "cornell-near-field")
    assert r["all"] < 0.97 and r["virtual"] < 0.3 and r["ring"] < 0.7, r
