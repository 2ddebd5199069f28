"""The pure parts of the Cycles translation in ``benchmarks/bench_vs_cycles.py`` (issue #30):
light units, the environment-map lookup, the spot profile, the lens, the tessellated sphere,
the measures. No bpy needed (the renders against Mitsuba: ``--check-lights``)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def B():
    sys.path.insert(0, str(BENCH))  # the script imports its sibling ``results``
    try:
        spec = importlib.util.spec_from_file_location("bench_vs_cycles",
                                                      BENCH / "bench_vs_cycles.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(BENCH))


def test_point_light_power_gives_mitsuba_intensity(B):
    """Cycles' point light of power P has intensity P/4π (a sphere of radius r: radiance
    P/(4π²r²)), so P = 4π I; a sphere light of radiance L: I = πr²L."""
    assert B.point_watts([3.0, 2.0, 1.0]) == pytest.approx(4 * math.pi * 3.0)
    r, L = 0.15, 2.0
    assert B.sphere_watts([L, 1.0, 0.5], r) == pytest.approx(B.point_watts([math.pi * r * r * L]))
    # radiance back from Blender's formula
    assert B.sphere_watts([L], r) / (4 * math.pi**2 * r**2) == pytest.approx(L)


def test_area_light_power_gives_mitsuba_radiance(B):
    """Cycles' one-sided area light of power P and area A has radiance P/(πA)."""
    assert B.area_watts([4.0, 3.0, 2.0], 0.5 * 0.3) / (math.pi * 0.15) == pytest.approx(4.0)


def test_light_colour_carries_the_channels(B):
    c = B.light_colour([4.0, 3.0, 2.0])
    assert c == pytest.approx([1.0, 0.75, 0.5])
    assert np.asarray(c) * B.area_watts([4.0, 3.0, 2.0], 1.0) == pytest.approx(
        np.pi * np.array([4.0, 3.0, 2.0]))
    assert B.light_colour([0.0, 0.0, 0.0]) == [0.0, 0.0, 0.0]


def test_envmap_axes_give_blender_the_pixel_mitsuba_reads(B):
    """Rejects a lookup mirrored or turned by a quarter: every direction maps to the same
    (u, v) in both conventions (Blender's v counted from the bottom row)."""
    m = B.envmap_axes()
    assert np.linalg.det(m) == pytest.approx(1.0)
    rng = np.random.default_rng(1)
    for d in rng.normal(size=(200, 3)):
        um, vm = B.mitsuba_equirect_uv(d)
        ub, vb = B.blender_equirect_uv(m @ d)
        assert (um - ub + 0.5) % 1.0 - 0.5 == pytest.approx(0.0, abs=1e-9)
        assert 1.0 - vm == pytest.approx(vb, abs=1e-9)


def test_envmap_rotation_is_mitsubas(B):
    """Mitsuba's ``rotate`` about +y by a (right-handed): +z turns towards +x."""
    r = B.rotation_y(90.0)
    assert r @ [0.0, 0.0, 1.0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)
    assert r @ r.T == pytest.approx(np.eye(3))


def test_spot_profile_is_linear_in_angle(B):
    cut, beam = 40.0, 25.0
    cos = np.cos(np.radians([0.0, 25.0, 32.5, 40.0, 60.0]))
    assert B.spot_falloff(cos, cut, beam) == pytest.approx([1.0, 1.0, 0.5, 0.0, 0.0])


def test_lens_and_aperture(B):
    """Cycles' aperture radius is lens[m]/(2N); the focal length in pixels is kept."""
    lens = B.lens_mm(fy=123.5, height=120)
    assert lens * 120 / 24.0 == pytest.approx(123.5)
    n = B.aperture_fstop(lens, 0.06)
    assert lens * 1e-3 / (2 * n) == pytest.approx(0.06)


def test_glossy_roughness_squares_to_alpha(B):
    assert B.glossy_roughness(0.15) ** 2 == pytest.approx(0.15)
    assert B.glossy_roughness(0.0) == 0.0


def test_uv_sphere_is_closed_outward_and_round(B):
    v, f = B.uv_sphere(48, 24)
    assert np.linalg.norm(v, axis=1) == pytest.approx(np.ones(len(v)))
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (np.sum(n * v[f].mean(axis=1), axis=1) > 0).all()  # counter-clockwise outside
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()  # watertight: every edge has two faces
    volume = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert volume == pytest.approx(4 / 3 * math.pi, rel=0.02)


def test_lights_mask_leaves_out_seen_lights_only(B):
    gt = np.full((10, 10, 3), 0.5)
    gt[2, 3] = 1e6
    gt[5, 5] = 20.0  # a bright but ordinary pixel (40× the median)
    keep = B.lights_mask(gt)
    assert not keep[2, 3] and keep.sum() == 99


def test_agreement_tells_noise_from_bias(B):
    rng = np.random.default_rng(2)
    gt = rng.uniform(0.2, 1.0, (60, 80, 3))
    se = np.full_like(gt, 0.01)
    truth = gt + rng.normal(0.0, 0.01, gt.shape)  # the ground truth is a noisy estimate
    fair = [truth + rng.normal(0.0, 0.02, gt.shape) for _ in range(2)]
    a = B.agreement(fair, gt, se)
    assert 0.8 < a["chi"] < 1.2 and a["bias"] < 0.01 and not B.disagrees(a)
    off = [x * 1.05 for x in fair]  # a 5 % unit error
    b = B.agreement(off, gt, se)
    assert b["chi"] > 2 and b["bias"] > 0.03 and B.disagrees(b)
    assert b["median_ratio"] == pytest.approx(1.05, abs=0.01)


def test_time_to_and_quantiles(B):
    pts = [(1.0, 0.1), (4.0, 0.05), (16.0, 0.025)]  # noise ∝ t^-1/2
    assert B.time_to(pts, 0.0125) == pytest.approx(64.0)
    assert B.quantiles([1.0, 2.0, 3.0, 0.5, 4.0]) == pytest.approx((2.0, 0.7, 0.5))


def test_equal_time_psnr_of_the_denoised_comparison(B):
    """``--denoise``'s equal-time PSNR: linear in log time between a curve's points, its best
    PSNR marked as a lower bound past its slowest point, no frame before its fastest, and
    onepass's spp spanning Cycles' (rejects an extrapolation past the measured points, or
    linear-in-time interpolation: at the geometric mean of 1 s and 4 s it must be midway)."""
    sys.path.insert(0, str(BENCH))
    try:
        from vs_cycles_denoised import arlight_spp, psnr_at
    finally:
        sys.path.remove(str(BENCH))
    curve = [(4.0, 30.0), (1.0, 20.0)]  # any order
    assert psnr_at(curve, 2.0) == (pytest.approx(25.0), "=")
    assert psnr_at(curve, 8.0) == (30.0, "≥")
    value, how = psnr_at(curve, 0.5)
    assert math.isnan(value) and how == "no frame"
    assert arlight_spp([1, 4, 16]) == [1, 2, 4, 8, 16, 32, 64]
