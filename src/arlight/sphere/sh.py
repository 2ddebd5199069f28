"""Real spherical harmonics of any order: basis, projection, evaluation, irradiance, rotation.

Basis (Franke thesis Eq. 4.4-4.7, Numerical-Recipes style):

* associated Legendre functions with the Condon-Shortley phase, by the recurrences

  - ``P_m^m(x) = (-1)^m (2m-1)!! (1-x^2)^{m/2}``
  - ``P_{m+1}^m(x) = x (2m+1) P_m^m(x)``  (the thesis prints ``x(2x+1)``: a typo)
  - ``(l-m) P_l^m = x (2l-1) P_{l-1}^m - (l+m-1) P_{l-2}^m``

* ``y_l^m = sqrt(2) K_l^m cos(m phi) P_l^m(cos theta)``        for ``m > 0``,
  ``y_l^m = sqrt(2) K_l^m sin(-m phi) P_l^{-m}(cos theta)``   for ``m < 0``,
  ``y_l^0 = K_l^0 P_l^0(cos theta)``,
  with ``K_l^m = sqrt((2l+1)/(4 pi) (l-|m|)!/(l+|m|)!)`` (|m|: the thesis prints m).
* linear index ``i = l(l+1) + m``.

Angles are those of ``docs/conventions.md``: ``theta`` from +Y (up), ``phi`` such that
``d = (sin theta sin phi, cos theta, -sin theta cos phi)``. So the SH "pole" is world +Y and
the linear band reads ``y_1^{-1} = -c x``, ``y_1^0 = c y``, ``y_1^1 = c z`` with
``c = sqrt(3/(4 pi))``. Coefficients are ``(n_coeffs, C)`` arrays (C = 3 for RGB) of
*radiance* SH unless a name says irradiance.

Exact integration uses a Gauss-Legendre (in cos theta) x uniform (in phi) product rule,
exact for spherical polynomials of the stated degree; rotation matrices, conversions to
foreign SH conventions and the triple-product tensor are all built with it, so they are
exact to rounding for any order.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from math import factorial

import numpy as np

from arlight.errors import InputError

Y00 = 0.5 / np.sqrt(np.pi)  # 0.28209479...


def n_coeffs(order: int) -> int:
    """Number of coefficients of SH up to band ``order`` (L): ``(L+1)^2``."""
    if order < 0:
        raise ValueError(f"SH order must be >= 0, got {order}")
    return (order + 1) ** 2


def order_of(n: int) -> int:
    """Inverse of :func:`n_coeffs`; raises if ``n`` is not a perfect square."""
    L = int(round(np.sqrt(n))) - 1
    if (L + 1) ** 2 != n or n < 1:
        raise InputError(f"{n} is not a valid number of SH coefficients ((L+1)^2)",
                         field="coefficients")
    return L


def sh_index(l: int, m: int) -> int:
    """Linear index ``i = l(l+1) + m`` (Franke Eq. 4.7)."""
    return l * (l + 1) + m


# ----------------------------------------------------------------------------- basis


def legendre_all(order: int, x: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """Associated Legendre ``P_l^m(x)`` for ``0 <= m <= l <= order`` (Franke Eq. 4.4).

    Condon-Shortley phase included; uses the three recurrences with the corrected
    ``(2m+1)`` factor.
    """
    x = np.asarray(x, dtype=np.float64)
    s = np.sqrt(np.clip(1.0 - x * x, 0.0, None))
    P: dict[tuple[int, int], np.ndarray] = {}
    pmm = np.ones_like(x)
    for m in range(order + 1):
        if m > 0:
            pmm = pmm * (-(2 * m - 1)) * s  # P_m^m = -(2m-1) s P_{m-1}^{m-1}
        P[(m, m)] = pmm
        if m + 1 <= order:
            P[(m + 1, m)] = x * (2 * m + 1) * pmm
        for l in range(m + 2, order + 1):
            P[(l, m)] = (x * (2 * l - 1) * P[(l - 1, m)] - (l + m - 1) * P[(l - 2, m)]) / (l - m)
    return P


def normalisation(l: int, m: int) -> float:
    """``K_l^m = sqrt((2l+1)/(4pi) (l-|m|)!/(l+|m|)!)`` (Franke Eq. 4.6 with |m|)."""
    am = abs(m)
    return float(np.sqrt((2 * l + 1) / (4 * np.pi) * factorial(l - am) / factorial(l + am)))


def _basis_parts(order: int, cos_theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Basis values for arrays of ``cos theta`` and ``phi`` broadcast together -> (..., n)."""
    cos_theta, phi = np.broadcast_arrays(
        np.asarray(cos_theta, dtype=np.float64), np.asarray(phi, dtype=np.float64)
    )
    P = legendre_all(order, cos_theta)
    out = np.empty(cos_theta.shape + (n_coeffs(order),), dtype=np.float64)
    sqrt2 = np.sqrt(2.0)
    for m in range(order + 1):
        if m == 0:
            for l in range(order + 1):
                out[..., sh_index(l, 0)] = normalisation(l, 0) * P[(l, 0)]
            continue
        c, s = np.cos(m * phi), np.sin(m * phi)
        for l in range(m, order + 1):
            k = sqrt2 * normalisation(l, m) * P[(l, m)]
            out[..., sh_index(l, m)] = k * c
            out[..., sh_index(l, -m)] = k * s  # sin(-(-m) phi) = sin(m phi)
    return out


def directions_to_angles(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World unit directions (..., 3) -> (cos theta, phi) in the convention of this module."""
    d = np.asarray(directions, dtype=np.float64)
    cos_theta = np.clip(d[..., 1], -1.0, 1.0)
    phi = np.arctan2(d[..., 0], -d[..., 2])
    return cos_theta, phi


def sh_basis(directions: np.ndarray, order: int) -> np.ndarray:
    """Real SH basis ``y_i(d)`` for unit directions ``(..., 3)`` -> ``(..., (order+1)^2)``."""
    ct, phi = directions_to_angles(directions)
    return _basis_parts(order, ct, phi)


def sh_eval(coeffs: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Evaluate ``sum_i c_i y_i(d)`` (Franke Eq. 4.9) -> ``(..., C)``."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    Y = sh_basis(directions, order_of(coeffs.shape[0]))
    return Y @ coeffs


# ----------------------------------------------------------------------------- quadrature


@lru_cache(maxsize=32)
def _quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    n_theta = degree // 2 + 1  # Gauss-Legendre with n nodes is exact up to degree 2n-1
    n_phi = degree + 1  # trapezoid in phi is exact for Fourier modes |k| <= degree
    x, w = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    ct = np.repeat(x, n_phi)
    st = np.sqrt(1 - ct * ct)
    ph = np.tile(phi, n_theta)
    dirs = np.stack([st * np.sin(ph), ct, -st * np.cos(ph)], axis=-1)
    weights = np.repeat(w, n_phi) * (2 * np.pi / n_phi)
    dirs.setflags(write=False)
    weights.setflags(write=False)
    return dirs, weights


def sphere_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions ``(K, 3)`` and weights ``(K,)`` (sr) integrating exactly every spherical
    polynomial of total degree <= ``degree``; the weights sum to 4 pi."""
    return _quadrature(int(degree))


def project_function(
    f: Callable[[np.ndarray], np.ndarray], order: int, degree: int | None = None
) -> np.ndarray:
    """Project a function of direction ``f(d (K,3)) -> (K,) or (K, C)`` onto SH
    (Franke Eq. 4.8, ``c_i = int f y_i dw``) with the exact product quadrature.

    ``degree`` is the quadrature's polynomial degree (default ``4*order + 8``): exact when
    ``f`` is band-limited to ``degree - order``.
    """
    dirs, w = sphere_quadrature(degree if degree is not None else 4 * order + 8)
    vals = np.asarray(f(dirs), dtype=np.float64)
    Y = sh_basis(dirs, order)
    return np.einsum("k,ki,k...->i...", w, Y, vals)


def project_samples(
    directions: np.ndarray, values: np.ndarray, weights: np.ndarray, order: int
) -> np.ndarray:
    """``c_i = sum_k w_k f_k y_i(d_k)`` for given samples (weights in sr, e.g. 4pi/N for
    uniform Monte Carlo or pixel solid angles)."""
    Y = sh_basis(directions, order)
    return np.einsum("k,ki,k...->i...", np.asarray(weights, np.float64), Y, values)


# ----------------------------------------------------------------------------- equirect


def _equirect_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row cos(theta), column phi and the exact per-row pixel solid angle (sr)."""
    theta_edges = np.linspace(0.0, np.pi, height + 1)
    cos_theta = np.cos((np.arange(height) + 0.5) * np.pi / height)
    phi = (np.arange(width) + 0.5) * (2 * np.pi / width)
    row_solid_angle = (np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:])) * (2 * np.pi / width)
    return cos_theta, phi, row_solid_angle


def _row_legendre_integrals(order: int, height: int, nodes: int = 6
                            ) -> dict[tuple[int, int], np.ndarray]:
    """``int_{row} P_l^m(cos th) sin th d th`` for every latitude row (Gauss-Legendre in
    ``x = cos th`` with ``nodes`` points per row) -> {(l, m): (H,)}."""
    edges = np.cos(np.linspace(0.0, np.pi, height + 1))  # x0 > x1 per row
    gx, gw = np.polynomial.legendre.leggauss(nodes)
    half = (edges[:-1] - edges[1:]) / 2
    mid = (edges[:-1] + edges[1:]) / 2
    x = mid[:, None] + half[:, None] * gx[None, :]
    w = half[:, None] * gw[None, :]
    P = legendre_all(order, x)
    return {k: (v * w).sum(axis=1) for k, v in P.items()}


def _column_trig_integrals(order: int, width: int) -> np.ndarray:
    """``int_{column} cos(m phi) d phi`` (m = 0..L) then ``sin(m phi)`` (m = 1..L) -> (W, 2L+1)."""
    e = np.linspace(0.0, 2 * np.pi, width + 1)
    cols = [np.diff(e)]
    m = np.arange(1, order + 1)
    s = np.sin(np.outer(e, m))
    c = np.cos(np.outer(e, m))
    cols_cos = (s[1:] - s[:-1]) / m
    cols_sin = (c[:-1] - c[1:]) / m
    return np.concatenate([np.stack(cols, axis=1), cols_cos, cols_sin], axis=1)


def project_equirect(image: np.ndarray, order: int,
                     band: Callable[[int, int, np.ndarray], np.ndarray] | None = None,
                     chunk_rows: int = 64) -> np.ndarray:
    """Project an equirect radiance map ``(H, W, C)`` onto SH -> ``(n, C)`` (Eq. 4.8).

    The map is taken as constant over each pixel and every basis function is integrated
    exactly over the pixel's solid angle: ``c_i = sum_p L_p int_p y_i dw`` (the pixel
    weights are the exact solid angles ``(2pi/W)(cos th0 - cos th1)``, equal to the
    conventions' ``(2pi/W)(pi/H) sin th`` up to O(H^-2)). So a constant map has exactly
    zero coefficients beyond l = 0, at any resolution.

    The integral separates: a per-row Fourier sum over columns (one matrix product) then
    a per-row Legendre sum: O(H W L + H L^2) instead of O(H W L^2). Rows are summed in
    bands of ``chunk_rows`` (float64 per band only), so a 4k float32 map is never copied
    whole. ``band(r0, r1, rows)``, when given, replaces each band of rows ``[r0, r1)``
    before it is projected: the SH of a modified map without building that map.
    """
    img = np.asarray(image)
    squeeze = img.ndim == 2
    if squeeze:
        img = img[..., None]
    H, W, C = img.shape
    trig = _column_trig_integrals(order, W)
    F = np.empty((H, trig.shape[1], C))
    step = max(1, int(chunk_rows))
    for r0 in range(0, H, step):
        rows = img[r0:r0 + step]
        if band is not None:
            rows = band(r0, r0 + rows.shape[0], rows)
        # (h, C, W) @ (W, K): a batched BLAS product, ~10x faster than the einsum here
        F[r0:r0 + rows.shape[0]] = np.matmul(
            rows.astype(np.float64).transpose(0, 2, 1), trig).transpose(0, 2, 1)
    P = _row_legendre_integrals(order, H)
    out = np.zeros((n_coeffs(order), C), dtype=np.float64)
    sqrt2 = np.sqrt(2.0)
    for mm in range(order + 1):
        for l in range(mm, order + 1):
            k = normalisation(l, mm) * P[(l, mm)]
            if mm == 0:
                out[sh_index(l, 0)] = k @ F[:, 0]
            else:
                out[sh_index(l, mm)] = sqrt2 * (k @ F[:, mm])
                out[sh_index(l, -mm)] = sqrt2 * (k @ F[:, order + mm])
    return out[:, 0] if squeeze else out


def sh_to_equirect(coeffs: np.ndarray, height: int) -> np.ndarray:
    """Evaluate SH ``coeffs (n, C)`` on an equirect grid -> ``(height, 2*height, C)`` float32.

    Uses the same separation as :func:`project_equirect` (Legendre per row, trig per column).
    """
    coeffs = np.asarray(coeffs, dtype=np.float64)
    squeeze = coeffs.ndim == 1
    if squeeze:
        coeffs = coeffs[:, None]
    order = order_of(coeffs.shape[0])
    H, W = int(height), 2 * int(height)
    ct, phi, _ = _equirect_grid(H, W)
    P = legendre_all(order, ct)
    C = coeffs.shape[1]
    # A[h, k, c]: per row, the coefficient of each trig term
    A = np.zeros((H, 2 * order + 1, C))
    sqrt2 = np.sqrt(2.0)
    for mm in range(order + 1):
        for l in range(mm, order + 1):
            k = normalisation(l, mm) * P[(l, mm)]
            if mm == 0:
                A[:, 0] += np.outer(k, coeffs[sh_index(l, 0)])
            else:
                A[:, mm] += sqrt2 * np.outer(k, coeffs[sh_index(l, mm)])
                A[:, order + mm] += sqrt2 * np.outer(k, coeffs[sh_index(l, -mm)])
    m = np.arange(order + 1)
    trig = np.concatenate([np.cos(np.outer(phi, m)), np.sin(np.outer(phi, m[1:]))], axis=1)
    out = np.einsum("hkc,wk->hwc", A, trig, optimize=True).astype(np.float32)
    return out[..., 0] if squeeze else out


# ----------------------------------------------------------------------------- irradiance


def clamped_cosine_band(l: int) -> float:
    """``A_hat_l``: SH convolution weight of the clamped cosine ``max(cos, 0)``
    (Ramamoorthi & Hanrahan 2001, Eq. 8-9): pi, 2pi/3, pi/4, 0, -pi/24, ...

    ``E_lm = A_hat_l L_lm`` turns radiance SH into irradiance SH.
    """
    if l == 0:
        return float(np.pi)
    if l == 1:
        return float(2 * np.pi / 3)
    if l % 2 == 1:
        return 0.0
    return float(
        2 * np.pi * (-1) ** (l // 2 - 1) / ((l + 2) * (l - 1))
        * factorial(l) / (2**l * factorial(l // 2) ** 2)
    )


def band_of_each_coeff(order: int) -> np.ndarray:
    """Band ``l`` of every linear index -> ``(n,)`` ints."""
    return np.concatenate([np.full(2 * l + 1, l) for l in range(order + 1)])


def irradiance_coeffs(coeffs: np.ndarray) -> np.ndarray:
    """Radiance SH -> irradiance SH (clamped-cosine convolution, R&H 2001).

    With 9 coefficients this is the classic irradiance environment map (average error
    below 3 % for natural maps, Franke Sec. 4.2).
    """
    coeffs = np.asarray(coeffs, dtype=np.float64)
    bands = band_of_each_coeff(order_of(coeffs.shape[0]))
    A = np.array([clamped_cosine_band(int(l)) for l in bands])
    return coeffs * A.reshape((-1,) + (1,) * (coeffs.ndim - 1))


def irradiance(coeffs: np.ndarray, normals: np.ndarray, max_order: int = 2) -> np.ndarray:
    """Irradiance (W/m^2) at surfaces with the given unit ``normals`` from radiance SH,
    truncated to ``max_order`` bands (2 = the 9-coefficient R&H approximation)."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    n = min(coeffs.shape[0], n_coeffs(max_order))
    return sh_eval(irradiance_coeffs(coeffs[:n]), normals)


# ----------------------------------------------------------------------------- rotation


def rotation_matrix(R: np.ndarray, order: int) -> np.ndarray:
    """SH rotation matrix ``M`` ``(n, n)`` with ``rotate(c) = M @ c`` such that the rotated
    function is ``g(d) = f(R^T d)`` (the environment turned by the 3x3 rotation ``R``).

    Built per band by exact projection, ``M_ij = int y_i(d) y_j(R^T d) dw``; it is
    block-diagonal by band and orthogonal, any order.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
        raise ValueError("R must be a 3x3 rotation matrix")
    dirs, w = sphere_quadrature(2 * order)
    Y = sh_basis(dirs, order)
    Yr = sh_basis(dirs @ R, order)  # rows: R^T d
    M = (Y * w[:, None]).T @ Yr
    bands = band_of_each_coeff(order)
    M[bands[:, None] != bands[None, :]] = 0.0
    return M


def rotate(coeffs: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotate SH coefficients by the world rotation ``R`` (see :func:`rotation_matrix`)."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    return rotation_matrix(R, order_of(coeffs.shape[0])) @ coeffs


# ----------------------------------------------------------------------------- light


LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB primaries


def linear_band_vector(coeffs: np.ndarray) -> np.ndarray:
    """The l = 1 part as a vector field: ``f_1(d) = a . d`` -> ``a`` ``(3, C)``."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    axes = np.eye(3)
    Y1 = sh_basis(axes, 1)[:, 1:4]  # (3 axes, 3 coeffs)
    return Y1 @ coeffs[1:4]


def dominant_direction(coeffs: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Dominant light direction (unit, pointing *toward* the light) from the first-order
    band (Sloan 2008, "Stupid SH tricks"): the direction maximising the linear part,
    using Rec. 709 luminance over the colour channels by default."""
    a = linear_band_vector(coeffs)
    if a.ndim == 2:
        w = LUMINANCE if weights is None and a.shape[1] == 3 else weights
        a = a @ (w if w is not None else np.ones(a.shape[1]) / a.shape[1])
    n = np.linalg.norm(a)
    return a / n if n > 0 else np.array([0.0, 1.0, 0.0])


def directional_light_coeffs(direction: np.ndarray, irradiance_rgb: np.ndarray,
                             order: int) -> np.ndarray:
    """SH of a delta light arriving *from* ``direction`` (toward the light) carrying
    ``irradiance_rgb`` (W/m^2 on a surface facing it): ``c_i = E y_i(direction)``."""
    y = sh_basis(np.asarray(direction, np.float64)[None], order)[0]
    return np.outer(y, np.asarray(irradiance_rgb, np.float64))


# ----------------------------------------------------------------------------- products


def triple_product_tensor(order: int) -> np.ndarray:
    """``C_ijk = int y_i y_j y_k dw`` ``(n, n, n)`` (Franke Eq. 5.1-5.7; the real
    Clebsch-Gordan / Gaunt coefficients), exact by quadrature of degree 3L.

    ``(f g)_i = sum_jk C_ijk f_j g_k`` up to truncation of the product to band L.
    """
    dirs, w = sphere_quadrature(3 * order)
    Y = sh_basis(dirs, order)
    C = np.einsum("k,ki,kj,kl->ijl", w, Y, Y, Y, optimize=True)
    C[np.abs(C) < 1e-13] = 0.0
    return C


def product(f: np.ndarray, g: np.ndarray, tensor: np.ndarray | None = None) -> np.ndarray:
    """SH projection of the product of two SH functions, truncated to ``f``'s order."""
    f = np.asarray(f, np.float64)
    g = np.asarray(g, np.float64)
    T = tensor if tensor is not None else triple_product_tensor(order_of(f.shape[0]))
    return np.einsum("ijk,j...,k...->i...", T, f, g)
