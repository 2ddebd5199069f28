"""``dic`` graded against the suite's Mitsuba ground truth, as dlpv, dir and dvct are
(:func:`tests.methods.test_dlpv.suite_quality`: MSE ratios composite / untouched frame at the
quick size, 64-spp photographs). DIC is a path tracer with an interpolated indirect term, so it
must beat the frame on the virtual pixels by a wide margin and on the relit ring too (measured
0.30–0.90 overall, 0.01–0.25 virtual, 0.34–0.81 ring) — except the virtual pixels of
glass-ring (0.66): its ring is a rough conductor, and DIC caches diffuse light only (Kán §4.2;
the glossy indirect reflection of the table is missing). Rejects an unlit or black object, a
delta of the wrong sign or scale, indirect light off by a factor."""

from __future__ import annotations

import pytest

from tests.methods.test_dlpv import suite_quality

SLOW = pytest.mark.slow  # ~5 s each on an idle machine; bunny-box runs in CI


@pytest.mark.parametrize("name", ["bunny-box", *(pytest.param(n, marks=SLOW) for n in (
    "cornell-near-field", "red-paper", "mirror-dragon", "outdoor-env", "glass-ring"))])
def test_quality_against_ground_truth(name):
    r = suite_quality("dic", name)
    virtual = 0.8 if name == "glass-ring" else 0.3
    assert r["all"] < 0.97 and r["virtual"] < virtual and r["ring"] < 0.9, r
