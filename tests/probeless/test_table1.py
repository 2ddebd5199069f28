"""Gruber Table 1 on synthetic sequences with known light (slow: renders and reconstructs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from arlight.probeless.experiment import score_sequence
from arlight.probeless.synthetic_rgbd import render_sequence

STUDIO = (Path(__file__).resolve().parents[2] / "src" / "arlight" / "data" / "light"
          / "panoramas" / "studio_small_03_512x256.hdr")


@pytest.mark.slow
@pytest.mark.parametrize("moving,floor,upper", [(True, 0.94, 0.27), (False, 0.90, 0.30)])
def test_sh_light_dominant_direction(moving, floor, upper):
    """Rendered frames (Mitsuba's path tracer, direct light) of the room under an animated
    16-coefficient cap light, reconstructed by the TSDF: the mean dot(d_est, d_true) over
    frames meets Gruber's Table 1 level (0.94-0.96) with a moving camera and stays ≥ 0.90 with
    a static one, for RM, REG4 and ART4; the mean upper-hemisphere error is ≤ 0.27 moving and
    ≤ 0.30 static (issue #33's acceptance, 0.3; measured 0.25 / 0.29 with the plane-fit
    normals, 0.285 / 0.344 with the mesh's own). Rejects a wrong sign convention (dot < 0), a
    transfer/observation mismatch (pixels vs samples off by one), interleaving that corrupts
    the fused transfer, and the reconstruction's mesh normals (``NORMAL_RADIUS = 0``)."""
    frames = render_sequence("sh", n=8, moving=moving, width=160, height=120, spp=64)
    scores = score_sequence(frames, ["RM", "REG4", "ART4"])
    for name, s in scores.items():
        assert s.dot.mean() >= floor, (name, s.dot)
        assert s.upper_error.mean() <= upper, (name, s.upper_error.mean())


@pytest.mark.slow
def test_real_hdr_map_dominant_direction():
    """A real HDR map (studio, lamps 54° up) rotated per frame: mean dot ≥ 0.94 (ART4)."""
    frames = render_sequence("hdr", n=8, moving=True, width=160, height=120, spp=64,
                             hdr=STUDIO)
    s = score_sequence(frames, ["ART4"])["ART4"]
    assert s.dot.mean() >= 0.94, s.dot
