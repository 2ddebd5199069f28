"""Full-resolution checks of ``reference`` (slow: minutes on 2 cores; `./dev test-all`)."""

import numpy as np
import pytest

from arlight.demo import demo_world_path
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import load_scene
from arlight.stats import agreement_fraction
from arlight.synthetic import synthesize


@pytest.mark.slow
def test_reference_unbiased_on_the_demo_world_at_640x480():
    world = load_scene(demo_world_path())
    assert world.resolution == (640, 480)
    photo = synthesize(world, spp=256, seed=3)
    layers = get_method("reference")(world.with_frame(photo.frame),
                                     RenderSettings(spp=64, seed=8))
    keep = (1.0 - layers.mask)[..., None]
    se = np.sqrt(layers.stderr["composite"] ** 2 + (keep * photo.frame_stderr) ** 2)
    assert agreement_fraction(layers.composite, se, photo.ground_truth,
                              photo.ground_truth_stderr) >= 0.99
    # the bunny's shadow is in the delta: clearly negative on real pixels
    z = layers.delta / np.maximum(layers.stderr["delta"], 1e-9)
    assert np.sum((z.max(axis=2) < -4) & (layers.mask == 0)) > 500
