"""Metric unit tests: exact identities on constructed images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.camera_response import Transfer
from arlight.evaluate import metrics as M

RNG = np.random.default_rng(3)


def img(h=24, w=32):
    return RNG.random((h, w, 3))


def test_psnr_of_identical_images_is_the_documented_cap():
    a = img()
    assert M.psnr(a, a) == M.PSNR_CAP == 100.0
    assert M.rmse(a, a) == 0.0


def test_psnr_of_a_known_mse():
    ref = np.zeros((10, 10, 3))
    ref[0, 0, 0] = 1.0  # R = max(ref) = 1
    test = ref + 0.1  # MSE = 0.01 exactly -> 20 dB
    assert M.mse(test, ref) == pytest.approx(0.01, rel=1e-12)
    assert M.psnr(test, ref) == pytest.approx(20.0, rel=1e-12)
    assert M.psnr(test, ref, peak=10.0) == pytest.approx(40.0, rel=1e-12)
    assert M.rmse(test, ref) == pytest.approx(0.1, rel=1e-12)


def test_region_restricts_the_average():
    ref = np.zeros((4, 4, 3))
    test = ref.copy()
    test[0, 0] = 2.0
    region = np.zeros((4, 4), bool)
    region[0, :2] = True
    assert M.mse(test, ref, region) == pytest.approx(2.0)  # (4 + 0) / 2
    assert M.mse(test, ref) == pytest.approx(4.0 / 16)
    assert math.isnan(M.mse(test, ref, np.zeros((4, 4), bool)))


def test_ssim_and_flip_of_identical_images_are_perfect():
    a = img()
    assert M.ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert M.flip(a, a) == 0.0
    assert M.flip(a * 5.0, a * 5.0, hdr=True) == 0.0


def test_ssim_and_flip_see_a_difference():
    a = img()
    b = np.clip(a + 0.2 * (RNG.random(a.shape) - 0.5), 0, 1)
    assert M.ssim(b, a) < 0.99
    assert M.flip(b, a) > 0.01
    assert M.flip(b * 4, a * 4, hdr=True) > 0.01


def test_heatmap_signs():
    ref = np.full((2, 3, 3), 0.5)
    test = ref.copy()
    test[0, 0] += 0.25  # too bright -> white end of blue ramp (gain 4: t = 1)
    test[0, 1] += 0.05  # slightly too bright -> dark blue
    test[1, 0] -= 0.25  # too dark -> yellow
    test[1, 1] -= 0.05  # slightly too dark -> dark red
    err = M.signed_error(test, ref)
    assert err[0, 0] > 0 > err[1, 0] and err[0, 2] == 0
    h = M.heatmap(err, gain=4.0)
    assert h[0, 0].tolist() == [255, 255, 255]
    assert h[1, 0].tolist() == [255, 255, 0]
    assert h[0, 1, 2] > 0 and h[0, 1, 0] == 0 and h[0, 1, 1] == 0  # blue only
    assert h[1, 1, 0] > 0 and h[1, 1, 1] == 0 and h[1, 1, 2] == 0  # red only
    assert h[0, 2].tolist() == [0, 0, 0]


def test_changed_region_uses_mask_and_significant_change():
    frame = np.full((3, 3, 3), 0.5)
    gt = frame.copy()
    gt[0, 0] = 0.2  # shadow, significant
    gt[0, 1] += 0.01  # within 3 standard errors of 0.01 -> noise
    mask = np.zeros((3, 3))
    mask[2, 2] = 0.5
    se = np.full_like(frame, 0.01 / np.sqrt(2))
    r = M.changed_region(frame, gt, mask, se, se)
    assert r.tolist() == [[True, False, False], [False, False, False], [False, False, True]]


def test_temporal_flicker():
    ref = np.zeros((3, 2, 2, 3))
    steady = ref + 0.3  # constant error: no flicker
    assert M.temporal_flicker(steady, ref) == 0.0
    blink = ref.copy()
    blink[1] += 0.2  # error 0, 0.2, 0 -> |Δ| = 0.2 twice
    assert M.temporal_flicker(blink, ref) == pytest.approx(0.2)
    with pytest.raises(ValueError):
        M.temporal_flicker(ref[:1])


def test_image_metrics_keys_and_display_psnr():
    t = Transfer("srgb", exposure=0.0)
    a = img() * 0.8
    m = M.image_metrics(a, a, t, prefix="changed_")
    assert m["changed_psnr"] == M.PSNR_CAP and m["changed_ssim"] == pytest.approx(1.0)
    assert m["changed_flip"] == 0.0 and m["changed_rmse"] == 0.0
