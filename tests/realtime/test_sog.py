"""Sum-of-Gaussians fit of the GGX glossy transfer (Franke Eqs. 4.25–4.26,
``arlight.realtime.sog``)."""

from __future__ import annotations

import math
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.jit import ensure_variant
from arlight.realtime.ibl_shading import MipEnvironment
from arlight.realtime.sog import SoGTables, fit_lobe, ggx_transfer, sog_table

ensure_variant()


def directional_albedo(alpha: float, cos_o: float, n: int = 500) -> float:
    """``∫ f_s cos θ_i dω`` of the GGX lobe by midpoint quadrature over the hemisphere in
    the normal's frame (independent of the fit's δ grid around the mirror direction)."""
    th = (np.arange(n) + 0.5) / n * (math.pi / 2)
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * (2 * math.pi)
    t, p = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    s = math.sqrt(1.0 - cos_o * cos_o)
    wo = np.broadcast_to(np.array([s, 0.0, cos_o]), wi.shape)
    dw = (math.pi / 2 / n) * (math.pi / n)
    return float(np.sum(ggx_transfer(alpha, wi, wo) * np.sin(t).ravel()) * dw)


@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.5])
def test_sog_reflects_a_constant_environment_like_the_ggx_albedo(alpha):
    """Constant environment L = 1: the SoG sum ``Σ w_k 2π σ_k²`` equals the directional
    albedo of the same GGX lobe, integrated in the normal's frame, within 3 % at four view
    angles; rejects a Gaussian integral other than 2πσ² (e.g. normalised Gaussians or
    σ√(2π)), a δ density without the exponential map's Jacobian sin|δ|/|δ|, and a fit grid
    that misses the lobe's tails."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        table = sog_table(alpha, 4)
    for j, c in enumerate(table.cos_o):
        ref = directional_albedo(alpha, float(c))
        assert table.albedo()[j] == pytest.approx(ref, rel=0.03), (alpha, c)


def test_poor_fit_is_flagged_with_a_warning():
    """One Gaussian for a rough lobe at a grazing view (cut by the horizon) has a large
    residual: the view is flagged and a RuntimeWarning names it, while three Gaussians near
    normal incidence fit well; rejects a fit that reports success whatever its error."""
    one = fit_lobe(0.5, 0.1, lobes=1)
    three = fit_lobe(0.5, 0.9, lobes=3)
    assert one.residual > 0.3 > 0.1 > three.residual
    with pytest.warns(RuntimeWarning, match="residual"):
        table = sog_table(0.5, 4, 1, max_residual=0.2)
    assert table.flagged.any() and not table.flagged.all()


def test_runtime_sog_under_a_constant_environment_gives_the_albedo():
    """Constant mip-mapped environment 1 through ``SoGTables.radiance`` at a few normals and
    view directions equals the fitted albedo at the fitted view angles (0.5 %) and stays
    within 2 % of the albedo interpolated in cos θ_o between them (the runtime interpolates
    w, µ, σ); a non-glossy shape gets 0; rejects a wrong table index (shape × views ×
    lobes), a wrong view interpolation or a lookup weighted by anything but ``w 2πσ²``."""
    alpha = 0.3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        tables = SoGTables.build([None, alpha])
        table = sog_table(alpha)
    env = MipEnvironment.build(np.ones((32, 64, 3), np.float32))
    cos_o = np.concatenate([table.cos_o[[1, 6, 12, 15]], [0.2, 0.5, 0.8, 0.97]])
    s = np.sqrt(1.0 - cos_o ** 2)
    n = mi.Vector3f(0.0, 1.0, 0.0)
    n = dr.gather(mi.Vector3f, n, dr.zeros(mi.UInt32, 8))
    v = mi.Vector3f(mi.Float(s.astype(np.float32)), mi.Float(cos_o.astype(np.float32)),
                    mi.Float(np.zeros(8, np.float32)))
    out = np.asarray(tables.radiance(env, dr.full(mi.Int32, 1, 8), n, v).x)
    expected = np.interp(cos_o, table.cos_o, table.albedo())
    np.testing.assert_allclose(out[:4], expected[:4], rtol=0.005)
    np.testing.assert_allclose(out[4:], expected[4:], rtol=0.02)
    none = np.asarray(tables.radiance(env, dr.zeros(mi.Int32, 8), n, v).x)
    assert np.all(none == 0.0)
