"""A light estimate feeds a scene: estimate from an HDR map, render under it."""

from pathlib import Path

import arlight
from arlight.io.images import read_linear, write_exr
from arlight.light.estimate import LightEstimate
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene
from tests.conftest import with_constant_frame

CAMERA = {"resolution": [8, 6], "fov_y_deg": 20,
          "look_at": {"origin": [0, 3, 0.01], "target": [0, 0, 0]}}
PLANE = [{"role": "real", "type": "disk", "radius": 100.0, "normal": [0, 1, 0],
          "material": {"type": "diffuse", "albedo": 0.8}}]


def test_estimated_lights_render_like_the_map_they_came_from(tmp_path):
    """Median-cut lights + SH remainder light a white plane about as the map itself does."""
    hdr = read_linear(Path(arlight.__file__).parent / "data/light/grace_latlong_256x128.hdr")
    est = LightEstimate.from_envmap(hdr, n_lights=16, sh_order=2)
    from_estimate = parse_scene({"camera": CAMERA, "shapes": PLANE,
                                 "lights": est.to_scene_lights("directional")})
    assert {x.type for x in from_estimate.lights} >= {"directional", "sh"}
    write_exr(tmp_path / "map.exr", hdr)
    from_map = parse_scene({"camera": CAMERA, "shapes": PLANE,
                            "lights": [{"type": "envmap", "file": "map.exr"}]},
                           base_dir=tmp_path)
    render = get_method("reference")
    settings = RenderSettings(spp=256, max_depth=2, seed=1)
    a = render(with_constant_frame(from_estimate), settings).mixed.mean()
    b = render(with_constant_frame(from_map), settings).mixed.mean()
    assert abs(a - b) / b < 0.05, (a, b)  # the SH remainder is band-limited
    # and the check can fail: dropping the SH remainder loses the sky's diffuse light
    lights_only = est.to_scene_lights("directional", include_sh=False)
    c = render(with_constant_frame(parse_scene({"camera": CAMERA, "shapes": PLANE,
                                                "lights": lights_only})), settings)
    assert abs(c.mixed.mean() - b) / b > 0.05
