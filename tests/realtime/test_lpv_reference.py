"""An LPV's irradiance from VPLs against the inverse-square law, through dlpv's own injection
and normalisation (issue #33, "LPV irradiance from one VPL against Φ/(πr²)·cos falloff").

``tests/realtime/test_sh_volume.py`` checks one VPL built in NumPy at a cell centre and
divides the read irradiance by :func:`~arlight.realtime.sh_volume.point_response`, which is
the mean of the same ratio over the same receivers (2/3/4 cells, 0/30/60°): its mean ratio
is 1 by construction, only the spread is tested. Here the VPLs are RSM-like texels — on a
surface at random sub-cell positions, tilted normals — injected with
:func:`~arlight.realtime.sh_volume.inject` (half a cell along the normal, Franke §4.3.1) at
the flux factor dlpv uses (:func:`~arlight.methods.dlpv.injection_scales`), propagated with
dlpv's defaults and read at receivers off the normaliser's set, against the irradiance of the
texels themselves written from the equation in NumPy:
``E(x) = Σ_i Φ_i/π · <n_i, ω_i>+ <n_x, −ω_i>+ / r_i²`` (W/m²; Franke Eq. 12's Lambertian
VPL of flux Φ_i at its texel)."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from arlight.jit import ensure_variant

ensure_variant()

from arlight.methods.dlpv import SPEC, injection_scales  # noqa: E402
from arlight.realtime import sh_volume as sv  # noqa: E402

CELL = 0.05
"""Cell size (m) of the test volume."""
SOURCE = np.array([10, 14, 15])
"""The cell (x, y, z) the texels' VPLs land in."""


def _vec(a: np.ndarray, kind):
    return kind(*(mi.Float(np.ascontiguousarray(a[:, i], np.float32)) for i in range(3)))


def _texels(m: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``m`` texel positions and unit normals (within 25° of +x) whose VPL position (texel +
    half a cell along the normal) falls uniformly in :data:`SOURCE`."""
    rng = np.random.default_rng(seed)
    tilt = np.radians(25.0) * np.sqrt(rng.random(m))
    az = 2 * math.pi * rng.random(m)
    nrm = np.stack([np.cos(tilt), np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az)], 1)
    pos = (SOURCE + rng.random((m, 3))) * CELL - 0.5 * CELL * nrm
    return pos, nrm


def _receivers() -> tuple[np.ndarray, np.ndarray]:
    """Receivers at 2.5/3/3.5/4 cells from the source cell's centre, 0/20/40/60° from +x
    (four azimuths each), facing the source: none at the normaliser's 2/3/4 cells and
    0/30/60° except the axis."""
    centre = (SOURCE + 0.5) * CELL
    pts, nrm = [], []
    for th in np.radians([0.0, 20.0, 40.0, 60.0]):
        for ph in np.radians([0.0, 90.0, 180.0, 270.0]):
            d = np.array([math.cos(th), math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph)])
            for r in (2.5, 3.0, 3.5, 4.0):
                pts.append(centre + r * CELL * d)
                nrm.append(-d)
    return np.array(pts), np.array(nrm)


def _true_irradiance(pos, nrm, flux, pts, pnrm) -> np.ndarray:
    """``Σ_i Φ_i/π <n_i, ω>+ <n_x, −ω>+ / r²`` (W/m²) from the texels' own positions."""
    v = pts[:, None, :] - pos[None]
    r = np.linalg.norm(v, axis=-1)
    u = v / r[..., None]
    emit = np.maximum(np.einsum("mk,xmk->xm", nrm, u), 0.0)
    recv = np.maximum(np.einsum("xk,xmk->xm", pnrm, -u), 0.0)
    return (flux[None] / math.pi * emit * recv / r ** 2).sum(1)


def _lpv_irradiance(pos, nrm, flux, pts, pnrm) -> np.ndarray:
    """The texels injected as dlpv injects its VPLs (flux × the VPL factor of
    :func:`injection_scales`, half a cell along the normal), propagated at dlpv's default
    size, steps and dampening, read with :func:`sv.query_irradiance` (W/m², red channel)."""
    o = SPEC.parse_options({})
    vol = sv.SHVolume.zeros(sv.Grid(np.zeros(3), CELL, o.volume_size))
    k_ind = injection_scales(o)[1]
    f = np.repeat((flux * k_ind)[:, None], 3, axis=1)
    sv.inject(vol, _vec(pos, mi.Point3f), _vec(nrm, mi.Vector3f), _vec(f, mi.Color3f),
              mi.Bool(True), offset=_vec(0.5 * CELL * nrm, mi.Vector3f))
    vol = sv.propagate(vol, o.steps, o.dampening)
    e = sv.query_irradiance(vol, _vec(pts, mi.Point3f), _vec(pnrm, mi.Vector3f))
    return np.array(e.x, np.float64)


def test_vpl_texels_light_receivers_by_the_inverse_square_law():
    """64 texels of 1/64 W in total (sub-cell positions, normals within 25° of +x):
    dlpv's LPV irradiance at 64 receivers 2.5–4 cells away (0–60° off axis) against the
    texels' own ``Φ cos θ_e cos θ_r / (π r²)``. Sum of the LPV's irradiance / sum of the
    true one within 0.85–1.5 (measured 1.26) and each receiver within 0.75–2.0 (measured
    0.94–1.73); behind the texels (3 cells, facing away) under a third of the front's mean.

    The measured 1.26 is a bias of the method, stated, not tuned away: the point response
    is measured from the cell centre, while a texel's VPL sits half a cell ahead of the
    texel on average (the injection offset) — the LPV sees the light closer than it is
    (1.73 at 2.5 cells on the axis, 1.07 at 4).

    Rejects: the lit plane's factor on VPLs (``1/plane_response`` instead of
    ``1/point_response``: 0.58), the lobe at Φ/4π or Φ instead of Φ/π (0.32, 3.97), the
    lobe's band 1 turned around (0.34) and an injection without the half-cell offset
    (0.49; all mutation-checked)."""
    pos, nrm = _texels(64)
    flux = np.full(len(pos), 1.0 / len(pos))
    pts, pnrm = _receivers()
    true = _true_irradiance(pos, nrm, flux, pts, pnrm)
    got = _lpv_irradiance(pos, nrm, flux, pts, pnrm)
    ratio = got / true
    total = got.sum() / true.sum()
    assert 0.85 <= total <= 1.5, total
    assert np.all((ratio >= 0.75) & (ratio <= 2.0)), ratio.round(2)
    back = (SOURCE + 0.5) * CELL - 3 * CELL * np.array([[1.0, 0.0, 0.0]])
    behind = _lpv_irradiance(pos, nrm, flux, back, np.array([[1.0, 0.0, 0.0]]))[0]
    assert behind < got.mean() / 3, (behind, got.mean())
