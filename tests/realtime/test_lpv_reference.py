"""An LPV's irradiance from VPLs against the inverse-square law, through dlpv's own injection
and normalisation (issue #33, "LPV irradiance from one VPL against Φ/(πr²)·cos falloff").

``tests/realtime/test_sh_volume.py`` checks one VPL built in NumPy at a cell centre and
divides the read irradiance by :func:`~arlight.realtime.sh_volume.point_response`, which is
the mean of the same ratio over the same receivers (2/3/4 cells, 0/30/60°): its mean ratio
is 1 by construction, only the spread is tested. Here the VPLs are RSM-like texels — on a
surface at random sub-cell positions, tilted normals — injected with
:func:`~arlight.realtime.sh_volume.inject` (half a cell along the normal, Franke §4.3.1) at
the flux factor dlpv uses (:func:`~arlight.methods.dlpv.injection_scales`), propagated with
dlpv's defaults and read as dlpv reads (half a cell along the receiver's normal,
:func:`~arlight.methods.dlpv.shade`) at receivers off the normaliser's set, against the
irradiance of the texels themselves written from the equation in NumPy:
``E(x) = Σ_i Φ_i/π · <n_i, ω_i>+ <n_x, −ω_i>+ / r_i²`` (W/m²; Franke Eq. 12's Lambertian
VPL of flux Φ_i at its texel).

Issue #33 (helper-48): the texel's light starts half a cell behind the VPL's cell on
average and dlpv reads half a cell in front of the receiver, so the cell-centre response
that dlpv divides by (0.88) makes one VPL 1.9× too bright here; the response derived with
both offsets (``point_response(offset=VPL_OFFSET)``, 1.71) reads it at 0.98. dlpv keeps the
cell-centre one (training A/B of the derived one: −0.09 dB; the LPV's far-field loss, which
the near-field excess compensates, docs/methods/dlpv.md "One VPL and the far field")."""

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


def _lpv_irradiance(pos, nrm, flux, pts, pnrm, k_ind: float | None = None) -> np.ndarray:
    """The texels injected as dlpv injects its VPLs (flux × the VPL factor of
    :func:`injection_scales`, half a cell along the normal), propagated at dlpv's default
    size, steps and dampening, read with :func:`sv.query_irradiance` half a cell along the
    receivers' normals, as :func:`arlight.methods.dlpv.shade` reads (W/m², red channel);
    ``k_ind`` replaces dlpv's VPL factor when given."""
    o = SPEC.parse_options({})
    vol = sv.SHVolume.zeros(sv.Grid(np.zeros(3), CELL, o.volume_size))
    if k_ind is None:
        k_ind = injection_scales(o)[1]
    f = np.repeat((flux * k_ind)[:, None], 3, axis=1)
    sv.inject(vol, _vec(pos, mi.Point3f), _vec(nrm, mi.Vector3f), _vec(f, mi.Color3f),
              mi.Bool(True), offset=_vec(0.5 * CELL * nrm, mi.Vector3f))
    vol = sv.propagate(vol, o.steps, o.dampening)
    e = sv.query_irradiance(vol, _vec(pts + 0.5 * CELL * pnrm, mi.Point3f),
                            _vec(pnrm, mi.Vector3f))
    return np.array(e.x, np.float64)


def _ratios(k_ind: float | None = None) -> tuple[float, np.ndarray, float]:
    """``(Σ E_LPV / Σ E_true, per-receiver E_LPV / E_true, E_LPV behind / mean E_LPV)`` of
    64 texels of 1/64 W in total (sub-cell positions, normals within 25° of +x) at the 64
    receivers of :func:`_receivers` and one 3 cells behind the texels, facing away."""
    pos, nrm = _texels(64)
    flux = np.full(len(pos), 1.0 / len(pos))
    pts, pnrm = _receivers()
    true = _true_irradiance(pos, nrm, flux, pts, pnrm)
    got = _lpv_irradiance(pos, nrm, flux, pts, pnrm, k_ind)
    back = (SOURCE + 0.5) * CELL - 3 * CELL * np.array([[1.0, 0.0, 0.0]])
    behind = _lpv_irradiance(pos, nrm, flux, back, np.array([[1.0, 0.0, 0.0]]), k_ind)[0]
    return got.sum() / true.sum(), got / true, behind / got.mean()


def test_offset_point_response_gives_the_inverse_square_law():
    """The one-VPL response derived with dlpv's offsets (:func:`sv.point_response` at
    :data:`sv.VPL_OFFSET`: the texel half a cell behind its VPL's cell on average, the
    receiver read half a cell towards it), as the VPLs' divisor: dlpv's LPV irradiance at
    64 receivers 2.5–4 cells away (0–60° off axis) against the texels' own
    ``Φ cos θ_e cos θ_r / (π r²)``: sum ratio within 0.85–1.15 (measured 0.98), each
    receiver within 0.6–1.5 (0.69–1.27); behind the texels under a fifth of the front's mean
    (0.10).

    Rejects the cell-centre response as the divisor (0.88: sum 1.89; dlpv's default, see
    the next test), the response without the read offset (1.08: 1.55) or with the texels at
    the cell centre (1.38: 1.21), the lobe at Φ/4π or Φ instead of Φ/π, the lobe's band 1
    turned around and an injection without the half-cell offset (mutation-checked)."""
    o = SPEC.parse_options({})
    k = 1.0 / sv.point_response(o.volume_size, o.steps, o.dampening, offset=sv.VPL_OFFSET)
    total, ratio, behind = _ratios(k)
    assert 0.85 <= total <= 1.15, total
    assert np.all((ratio >= 0.6) & (ratio <= 1.5)), ratio.round(2)
    assert behind < 0.2, behind


def test_dlpv_reads_one_vpl_too_bright_by_its_cell_centre_response():
    """dlpv's own VPL factor (:func:`injection_scales`: 1 / the cell-centre response, 0.88)
    on the same texels and receivers: the sum ratio 1.6–2.2 (measured 1.89), the bias of the
    method, stated and bounded, not removed — dividing by the derived 1.71 instead cost
    0.09 dB on the training worlds and halved the cube's bleed against a path tracer
    (0.92× → 0.47×), because the LPV loses the light it should carry beyond 4 cells
    (docs/methods/dlpv.md "One VPL and the far field").

    Rejects a change of dlpv's VPL factor in either direction by ≥ 15 % without this
    statement being revised: the derived response (sum 0.98), the lit plane's factor
    (1/plane_response: ~0.9), Φ/4π (~0.5) — mutation-checked."""
    total, ratio, behind = _ratios()
    assert 1.6 <= total <= 2.2, total
    assert np.all((ratio >= 1.0) & (ratio <= 2.6)), ratio.round(2)
    assert behind < 0.2, behind
