"""Reduced-size frames (studio drags, ``arlight live --render-scale``) of dir and dlpv take
one G-buffer sample (issue #32 after #33's 4-sample default: the live frame rate fell from
12.4 / 11.3 to 9.5 / 8.3 frames/s at render scale 1/2)."""

from __future__ import annotations

import pytest

from arlight.methods import RenderSettings, get_method
from arlight.sequence.job import scaled_settings


@pytest.mark.parametrize("name", ["dir", "dlpv"])
def test_reduced_frames_take_one_gbuffer_sample(name):
    """Rejects drag options that divide the 4 samples by the factor (2 at render scale 1/2,
    half the frame's cost) and a full-size frame that loses its antialiasing."""
    spec = get_method(name).spec
    opts = spec.parse_options({})
    assert opts.gbuffer_spp == 4
    assert spec.drag(opts, 2)["gbuffer_spp"] == 1
    assert scaled_settings(name, RenderSettings(), 2).options["gbuffer_spp"] == 1
    assert scaled_settings(name, RenderSettings(), 1).options.get("gbuffer_spp", 4) == 4
