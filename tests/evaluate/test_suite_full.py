"""Suite scenes at the papers' resolutions (slow: minutes on 2 cores; `./dev test-all`)."""

import numpy as np
import pytest

from arlight.evaluate.suite import get_scene
from arlight.methods import RenderSettings, get_method
from arlight.stats import agreement_fraction


@pytest.mark.slow
@pytest.mark.parametrize("name", ["bunny-box", "cornell-near-field"])
def test_reference_matches_ground_truth_at_full_resolution(name):
    s = get_scene(name, quick=False)
    photo = s.photo(spp=256)
    layers = get_method("reference")(s.ar_scene(photo), RenderSettings(spp=64, seed=5))
    keep = (1.0 - layers.mask)[..., None]
    se = np.sqrt(layers.stderr["composite"] ** 2 + (keep * photo.frame_stderr) ** 2)
    assert agreement_fraction(layers.composite, se, photo.ground_truth,
                              photo.ground_truth_stderr) >= 0.99
