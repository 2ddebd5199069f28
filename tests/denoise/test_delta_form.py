"""The change's default form ``delta = auto`` (issue #31): ``ratio`` on denoised frames,
``additive`` on raw ones, chosen on training worlds (docs/methods/denoising.md)."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.denoise.options import delta_form
from arlight.methods import RenderSettings, get_method
from tests.conftest import area_light_scene, load


def test_auto_is_ratio_when_denoised_and_additive_when_not():
    """Rejects an ``auto`` that applies the ratio to raw frames (noisy ``s``: −2.5 dB on a
    training world at 1 spp) or never; explicit forms are kept either way."""
    assert delta_form({"delta": "auto"}, denoised=True) == "ratio"
    assert delta_form({"delta": "auto"}, denoised=False) == "additive"
    for form in ("additive", "ratio"):
        assert delta_form({"delta": form}, denoised=True) == form
        assert delta_form({"delta": form}, denoised=False) == form
    assert delta_form({}, denoised=True) == "additive"  # a method without the option


def _render(scene, **options):
    return get_method("onepass")(scene, RenderSettings(spp=2, seed=1, options=options))


def test_default_render_is_additive_raw_and_ratio_denoised():
    """onepass with default options renders bit for bit what the explicit form renders:
    ``additive`` undenoised, ``ratio`` denoised (and the two denoised forms differ, so the
    comparison can fail). Rejects a default that changes the undenoised output the
    unbiasedness tests and #33's equal-time peer read."""
    pytest.importorskip("pyoidn")
    scene = load(area_light_scene(48, 36))
    scene = scene.with_frame(np.full((36, 48, 3), 0.3, np.float32))
    assert np.array_equal(_render(scene).composite,
                          _render(scene, delta="additive").composite)
    dn = _render(scene, denoise="oidn").composite
    assert np.array_equal(dn, _render(scene, denoise="oidn", delta="ratio").composite)
    assert not np.array_equal(dn, _render(scene, denoise="oidn", delta="additive").composite)
