"""``dic`` graded against the suite's Mitsuba ground truth, as dlpv, dir and dvct are
(:func:`tests.methods.test_dlpv.suite_quality`: MSE ratios composite / untouched frame at the
quick size, 64-spp photographs). DIC is a path tracer with an interpolated indirect term, so it
must beat the frame by a wide margin everywhere, the relit ring included. Rejects an unlit or
black object, a delta of the wrong sign or scale, indirect light off by a factor."""

from __future__ import annotations

import pytest

from tests.methods.test_dlpv import suite_quality


@pytest.mark.parametrize("name", ["bunny-box", "cornell-near-field", "red-paper",
                                  "mirror-dragon", "outdoor-env", "glass-ring"])
def test_quality_against_ground_truth(name):
    r = suite_quality("dic", name)
    assert r["all"] < 0.9 and r["virtual"] < 0.3 and r["ring"] < 0.9, r
