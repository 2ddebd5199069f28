"""Light estimation from observed shading and transfer (Gruber et al. 2014, digest E5, E8).

Per colour channel ``c`` the 16 radiance SH coefficients ``l_c`` minimise

    Σ_i ( a_ic/π · T(x_i)·l_c − b_ic )²  +  λ ‖l_c‖²                      (E5)

over the regular sample set: ``b_ic`` the observed *linear* pixel value (W/(sr·m²)),
``T(x_i)`` the real-scene transfer (E3), ``a_ic`` the diffuse albedo at the sample (from the
proxy's material; a reconstruction gets one assumed uniform albedo, so the overall scale of
``l`` is only as good as that assumption — Gruber absorbs it into ``l``). ``λ = ridge · σ_max²``
(``σ``: singular values of the system matrix) damps directions of light the scene cannot
see (band 3 is observable only through occlusion; the lower hemisphere not at all on a floor).

The conditioning is reported: a single unoccluded plane gives rank-1 transfer, the light is
then *undetermined* — the result says so (``determined = False``, low confidence) instead of
returning a solution of noise. The dominant direction (E8) comes from the linear band,
luminance-weighted (:func:`arlight.sphere.sh.dominant_direction`, our SH convention).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from arlight.light.estimate import LightEstimate
from arlight.probeless.directions import N_COEFFS
from arlight.sphere import sh as SH

MAX_CONDITION = 1e3
"""Singular values below ``σ_max / MAX_CONDITION`` count as unobservable. The floor-and-boxes
room has ``σ_16/σ_1 ≈ 4e-3`` (band 3 seen only through occlusion); a reconstructed plane has
``σ_2/σ_1 ≈ 5e-3`` and then < 2e-4 (marching-cubes normal noise), so 1e3 separates them."""
DEFAULT_RIDGE = 1e-3
"""Tikhonov weight relative to ``σ_max²``. Chosen with the reconstruction's smoothing
(:data:`arlight.probeless.reconstruct.SMOOTH_ITERATIONS`) on *training* light setups — the
modelled room under three real HDR maps, static and moving camera, path traced with
interreflection — by the median upper-hemisphere error, jointly with the visibility range
under a near-lamp guard (the range stayed Gruber's 10 cm), and reported on Gruber's SH cap
light, held out (issue #33, ``benchmarks/tune_light_estimation.py
--part setups``, benchmarks/RESULTS.md): training median 0.622 → 0.568, Gruber's light
0.567 → 0.352 (static) and 0.357 → 0.291 (moving) against the old 3e-3 without smoothing;
re-chosen (kept) with the plane-fit normals (:data:`arlight.probeless.reconstruct.NORMAL_RADIUS`)
and E3 as unoccluded minus blocked: Gruber's light 0.290 / 0.251.
3e-3 had been chosen on those very Gruber sequences on the raw marching-cubes mesh, whose
staircase normals a strong ridge partly hid. On the generated worlds of issue #30 (light at
the objects, local lamps; no reconstruction) the training median SH error fell with *more*
ridge, toward the zero estimate; 1e-3 has not been re-measured there (the #30 note: a
re-choice reports on seeds from 1 000 024 on)."""
MIN_RANK = 4
"""Fewer observable light directions than this: the light is undetermined (at least the
constant and the linear band must be seen for a dominant direction)."""


@dataclass
class SHLightFit:
    """Result of :func:`estimate_light`.

    Attributes:
        sh: ``(16, 3)`` radiance SH of the light (our basis).
        direction: unit dominant direction toward the light (E8), world space.
        condition: ``σ_max / σ_min`` of the (albedo-free) system matrix; ``inf`` if singular.
        rank: number of singular values above ``σ_max / max_condition``.
        samples: rows used.
        residual_rms: RMS of ``a/π T·l − b`` over the samples, per channel ``(3,)``.
        determined: whether ``rank >= min_rank`` (else ``sh`` is only the damped
            minimum-norm part the scene constrains, and ``direction`` is not meaningful).
        message: why not determined (empty otherwise).
    """

    sh: np.ndarray
    direction: np.ndarray
    condition: float
    rank: int
    samples: int
    residual_rms: np.ndarray
    determined: bool
    message: str = ""
    singular_values: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def confidence(self) -> float:
        """Observable share of the 16 coefficients, ``rank/16``, in [0, 1]."""
        return float(self.rank) / N_COEFFS

    def to_light_estimate(self, timestamp: float = 0.0) -> LightEstimate:
        """A :class:`~arlight.light.estimate.LightEstimate`: all light in the SH (the dominant
        direction as ``main_direction`` with zero irradiance, so nothing is counted twice)."""
        return LightEstimate(main_direction=self.direction, main_irradiance=np.zeros(3),
                             sh=self.sh, timestamp=timestamp,
                             confidence=min(1.0, self.confidence))


def estimate_light(transfer: np.ndarray, observed: np.ndarray, albedo: np.ndarray | float,
                   ridge: float = DEFAULT_RIDGE, max_condition: float = MAX_CONDITION,
                   min_rank: int = MIN_RANK) -> SHLightFit:
    """Solve E5 for the 16×3 radiance SH.

    Args:
        transfer: ``T_real`` of the samples ``(M, 16)`` (sr).
        observed: linear pixel values ``b`` ``(M, 3)`` (W/(sr·m²)).
        albedo: diffuse albedo per sample ``(M, 3)`` or one number.
        ridge: Tikhonov weight relative to ``σ_max²`` of the channel's system (0: plain
            least squares on the observable subspace).
        max_condition: singular values below ``σ_max / max_condition`` are not observable.
        min_rank: below this rank the light is reported undetermined.
    """
    T = np.asarray(transfer, np.float64).reshape(-1, N_COEFFS)
    b = np.asarray(observed, np.float64).reshape(-1, 3)
    a = np.broadcast_to(np.asarray(albedo, np.float64), b.shape)
    m = len(T)
    if len(b) != m:
        raise ValueError(f"{m} transfer rows but {len(b)} observations")
    if m == 0:
        return SHLightFit(np.zeros((N_COEFFS, 3)), np.array([0.0, 1.0, 0.0]), float("inf"),
                          0, 0, np.zeros(3), False, "no samples")
    # Normal equations on 16×16 matrices: O(M·256) per channel, no M×16 factorisation
    # (float64; the room's condition 250 squares to 6e4, far from trouble).
    ev = np.clip(np.linalg.eigvalsh(T.T @ T)[::-1], 0.0, None)
    s = np.sqrt(ev)
    smax = float(s[0])
    rank = int(np.count_nonzero(s > smax / max_condition)) if smax > 0 else 0
    cond = smax / float(s[-1]) if s[-1] > 0 else float("inf")
    sh = np.zeros((N_COEFFS, 3))
    res = np.zeros(3)
    for c in range(3):
        A = T * (a[:, c] / np.pi)[:, None]
        w, V = np.linalg.eigh(A.T @ A)
        wmax = float(w.max())
        keep = w > wmax / max_condition ** 2 if wmax > 0 else np.zeros_like(w, bool)
        inv = np.where(keep, 1.0 / np.where(keep, w + ridge * wmax, 1.0), 0.0)
        sh[:, c] = V @ (inv * (V.T @ (A.T @ b[:, c])))
        res[c] = float(np.sqrt(np.mean((A @ sh[:, c] - b[:, c]) ** 2)))
    determined = rank >= min_rank
    message = "" if determined else (
        f"light undetermined: the samples constrain only {rank} of {N_COEFFS} SH "
        f"coefficients (condition {cond:.3g}); a single plane or too few normals")
    return SHLightFit(sh=sh, direction=SH.dominant_direction(sh), condition=cond, rank=rank,
                      samples=m, residual_rms=res, determined=determined, message=message,
                      singular_values=s)


__all__ = ["DEFAULT_RIDGE", "MAX_CONDITION", "MIN_RANK", "SHLightFit", "estimate_light"]
