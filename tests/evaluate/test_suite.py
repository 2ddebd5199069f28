"""The scene suite: every scene loads, synthesises, and `reference` matches its ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.evaluate.suite import get_scene, list_scenes
from arlight.methods import RenderSettings, get_method
from arlight.stats import agreement_fraction

EXPECTED = {"bunny-box", "glass-ring", "mirror-dragon", "red-paper", "cornell-near-field",
            "outdoor-env"}
FULL = {"cornell-near-field": (960, 540)}


def test_suite_lists_the_papers_scenes():
    assert EXPECTED <= set(list_scenes())


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_scene_loads_with_documentation(name):
    quick, full = get_scene(name, quick=True), get_scene(name, quick=False)
    assert quick.resolution[0] == 80
    assert full.resolution == FULL.get(name, (640, 480))
    # quick keeps the aspect ratio and the field of view
    assert quick.resolution[1] == round(80 * full.resolution[1] / full.resolution[0])
    assert quick.world.camera.fy / quick.resolution[1] == pytest.approx(
        full.world.camera.fy / full.resolution[1])
    assert quick.paper_figure and quick.description
    assert quick.world.has_virtual and quick.world.real_shapes
    assert quick.proxy.frame is None


def test_unknown_scene_names_the_known_ones():
    with pytest.raises(InputError, match="bunny-box"):
        get_scene("no-such-scene")


def test_cornell_lights_are_rohmers():
    lights = {x.name: x for x in get_scene("cornell-near-field").world.lights}
    assert lights["ceiling_light"].params["radiance"] == [15.0] * 3
    assert lights["window"].params["radiance"] == [3.0] * 3


def composite_stderr(layers, photo) -> np.ndarray:
    """Standard error of the reference composite including the frame's own noise
    (the composite carries I_c in real pixels, an independent Monte Carlo estimate)."""
    frame_part = (1.0 - layers.mask)[..., None] * photo.frame_stderr
    return np.sqrt(np.square(layers.stderr["composite"]) + np.square(frame_part))


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_reference_matches_ground_truth(name, eval_cache):
    s = get_scene(name, quick=True)
    photo = s.photo(spp=64, cache_dir=eval_cache)
    assert photo.frame.shape == photo.ground_truth.shape == (*s.resolution[::-1], 3)
    assert photo.mask.max() > 0  # the virtual objects are in view
    layers = get_method("reference")(s.ar_scene(photo), RenderSettings(spp=64, seed=5))
    frac = agreement_fraction(layers.composite, composite_stderr(layers, photo),
                              photo.ground_truth, photo.ground_truth_stderr)
    assert frac >= 0.99


def test_frame_alone_disagrees_with_ground_truth(eval_cache):
    """The agreement test can fail: the frame without the object is not the ground truth."""
    s = get_scene("bunny-box", quick=True)
    photo = s.photo(spp=64, cache_dir=eval_cache)
    frac = agreement_fraction(photo.frame, photo.frame_stderr, photo.ground_truth,
                              photo.ground_truth_stderr)
    assert frac < 0.99
