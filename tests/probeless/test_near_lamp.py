"""A near lamp: the default visibility range must keep E5's estimate pointing at it."""

from __future__ import annotations

import dataclasses

import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.evaluate.suite import get_scene
from arlight.methods.probeless import OPTIONS
from arlight.probeless.pipeline import Pipeline, Settings
from arlight.probeless.transfer import MAX_DISTANCE
from arlight.synthetic import synthesize


def _lamp_scene():
    """bunny-box's world (the geometry that rendered the frame, virtual objects left out) and
    a Mitsuba frame of it, direct light only; the lamp's centre from the scene file."""
    world = get_scene("bunny-box", quick=True).world
    frame = synthesize(world, spp=16, seed=1, max_depth=2).frame
    real = dataclasses.replace(world, shapes=[s for s in world.shapes if not s.is_virtual],
                               lights=[])
    (lamp,) = [lt for lt in world.lights if lt.type == "area"]
    centre = np.asarray(lamp.params["to_world"], np.float64)[:3, 3]
    return real, frame, centre


def _dot(real, frame, centre, max_distance: float) -> float:
    pipe = Pipeline(build_views(real), "REG4", Settings(max_distance=max_distance),
                    shapes=real.shapes)
    fit = pipe.process(real.camera, frame, None, shade=False).fit
    to_lamp = centre - np.array([0.0, 0.09, 0.0])  # from the virtual objects' centre
    return float(fit.direction @ to_lamp / np.linalg.norm(to_lamp))


def test_default_range_keeps_a_near_lamp():
    """bunny-box's 25 cm lamp 0.8 m above the table, Mitsuba-rendered (direct light, the
    exact geometry as the proxy, so neither reconstruction nor interreflection is involved):
    at the default visibility range the estimated dominant direction is within 15° of the
    lamp as seen from the virtual objects (the lamp's position read from the scene file, not
    from the method). Rejects a default range long enough that the lamp's long shadows enter
    the distant-light fit — at 1 m the direction turns ~45° toward the camera (dot 0.70,
    issue #33's measurement) because no single distant direction casts a near lamp's shadows
    where they fall; and a method option whose default differs from the pipeline's."""
    assert OPTIONS["max_distance"].default == Settings().max_distance == MAX_DISTANCE
    real, frame, centre = _lamp_scene()
    assert _dot(real, frame, centre, Settings().max_distance) > np.cos(np.radians(15.0))


def test_near_lamp_setup_faces_its_target():
    """The tune's near-lamp training setup (``render_sequence("lamp")``): the true light at
    the objects, measured by Mitsuba (``incident_sh``), has its dominant direction within 10°
    of the lamp's direction from the objects, and the frame is lit (the room's median pixel
    over 3× what the ambient 0.04 alone gives an albedo of 0.6). Rejects a one-sided lamp
    turned away from the scene (only the ambient left: no dominant direction, a dark frame)
    or one placed on the wrong side of the objects."""
    from arlight.probeless.synthetic_rgbd import render_sequence
    from arlight.sphere import sh as SH

    (f,) = render_sequence("lamp", n=1, width=40, height=30, spp=4)
    assert SH.dominant_direction(f.true_sh) @ f.true_direction > np.cos(np.radians(10.0))
    seen = f.rgbd.depth > 0  # pixels on the room (not the ambient seen directly)
    assert float(np.median(f.rgbd.colour[seen])) > 3 * 0.04 * 0.6
