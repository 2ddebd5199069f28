"""Light extraction from environment maps: median cut, variance minimisation, Kan's blob.

Every extracted light stands for a set of pixels ``R`` and carries (the colour/power
rule used throughout arlight):

* ``direction``: unit vector *toward* the light, the energy-weighted centroid on the
  sphere, ``normalize(sum_p w_p d_p)`` with ``w_p = Y(L_p) Omega_p`` (luminance x pixel
  solid angle);
* ``irradiance``: RGB ``E = sum_{p in R} L_p Omega_p`` (W/m^2), the irradiance that
  region delivers to a surface facing it. As a directional light this is its
  ``irradiance``; as a point light at distance ``D`` its intensity is ``I = E D^2``
  (W/sr), which gives the same irradiance at the origin.

So the lights of a partition of the sphere add up exactly to the map's integral
``int L dw``, and a light set plus the SH of the remainder reproduces the map's energy.

Algorithms:

* :func:`median_cut` (Debevec 2005, "A median cut algorithm for light probe sampling"):
  recursively split every region along its longer side (the longitude extent scaled by
  ``cos`` of the latitude) where its energy is halved; ``2^k`` regions after ``k`` rounds.
* ``method="variance"`` (Viriyothai & Debevec 2009, used by DLPV, Franke 2013 Sec. 3.1):
  the same recursion, but the cut minimises the summed energy-weighted spatial variance of
  the two halves instead of halving the energy.
* :func:`brightest_blob` (Kan 2014 Sec. 3.2.1): threshold -> connected components ->
  largest blob (by solid angle) -> its direction x ``room_size`` gives a point light.
* :func:`highlight_regions`: the connected highlight regions of an equirect map on the
  sphere (joined across the longitude seam and around each pole, fragments closer than a
  gap merged), one light per region: a compact source (the sun) is one light with its full
  energy and its angular size, an area source (window, softbox) keeps its extent.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from arlight.sphere.envmap import equirect_row_solid_angle
from arlight.sphere.sh import LUMINANCE


@dataclass
class ExtractedLight:
    """A light standing for a part of the environment.

    ``direction``: unit vector from the scene *toward* the light; ``irradiance``: RGB
    W/m^2 at normal incidence; ``solid_angle``: sr covered by its pixels; ``spread``:
    angular radius (rad) of the uniform cap with the same energy-weighted mean cosine
    about ``direction`` (``acos(2 |sum e d| / sum e - 1)``; 0 for a point, the disc radius
    for a uniform disc: the size to use for soft shadows).
    """

    direction: np.ndarray
    irradiance: np.ndarray
    solid_angle: float = 0.0
    spread: float = 0.0

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, np.float64).reshape(3)
        n = np.linalg.norm(d)
        self.direction = d if abs(n - 1.0) < 1e-12 else d / n  # keep unit input bit-exact
        self.irradiance = np.asarray(self.irradiance, np.float64).reshape(3)
        self.solid_angle = float(self.solid_angle)
        self.spread = float(self.spread)

    def to_directional(self) -> dict:
        """Scene-file table; ``direction`` there is the direction the light *travels*."""
        return {"type": "directional", "direction": (-self.direction).tolist(),
                "irradiance": self.irradiance.tolist()}

    def to_point(self, room_size: float, origin: np.ndarray | None = None) -> dict:
        """Point light at ``origin + direction * room_size`` with ``I = E room_size^2``."""
        o = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
        return {"type": "point", "position": (o + self.direction * room_size).tolist(),
                "intensity": (self.irradiance * room_size**2).tolist()}

    def to_dict(self) -> dict:
        return {"direction": self.direction.tolist(), "irradiance": self.irradiance.tolist(),
                "solid_angle": self.solid_angle, "spread": self.spread}

    @classmethod
    def from_dict(cls, d: dict) -> ExtractedLight:
        return cls(direction=d["direction"], irradiance=d["irradiance"],
                   solid_angle=d.get("solid_angle", 0.0), spread=d.get("spread", 0.0))


# ----------------------------------------------------------------------------- helpers


def _sat(a: np.ndarray) -> np.ndarray:
    """Summed-area table with a zero first row/column: ``S[r, c] = sum a[:r, :c]``."""
    S = np.zeros((a.shape[0] + 1, a.shape[1] + 1) + a.shape[2:], dtype=np.float64)
    S[1:, 1:] = np.cumsum(np.cumsum(a, axis=0, dtype=np.float64), axis=1)
    return S


def _cumulative(slices: np.ndarray) -> np.ndarray:
    """``[0, s0, s0 + s1, ...]``: cumulative energy of the slices along a split axis."""
    return np.concatenate([[0.0], np.cumsum(slices, dtype=np.float64)])


class _Tables:
    """Per-pixel energy of an equirect map, separable direction/solid-angle factors, and
    (lazily, for variance minimisation only) summed-area tables of the energy moments."""

    def __init__(self, image: np.ndarray) -> None:
        self.img = np.clip(np.asarray(image, np.float64)[..., :3], 0.0, None)
        H, W = self.img.shape[:2]
        self.H, self.W = H, W
        # everything about a pixel's direction and solid angle is separable in row (θ)
        # and column (φ), so region sums never need an (H, W, 3) direction array
        self.omega_row = equirect_row_solid_angle(H, W)
        theta = (np.arange(H) + 0.5) * np.pi / H
        phi = (np.arange(W) + 0.5) * 2 * np.pi / W
        self.sin_t, self.cos_t = np.sin(theta), np.cos(theta)
        self.sin_p, self.cos_p = np.sin(phi), np.cos(phi)
        self.e = (self.img @ LUMINANCE) * self.omega_row[:, None]

    def energy(self, r0: int, r1: int, c0: int, c1: int) -> float:
        return float(self.e[r0:r1, c0:c1].sum())

    @cached_property
    def moments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        rows = np.arange(self.H, dtype=np.float64)[:, None] + 0.5
        cols = np.arange(self.W, dtype=np.float64)[None, :] + 0.5
        e = self.e
        return _sat(e * rows), _sat(e * cols), _sat(e * rows**2), _sat(e * cols**2)

    def light(self, r0: int, r1: int, c0: int, c1: int) -> ExtractedLight:
        """The region's light; direct sums (the regions partition the map: O(H W) total).

        Direction: ``Σ e d`` with ``d = (sinθ sinφ, cosθ, −sinθ cosφ)``, summed column-wise
        first (``e @ sinφ`` etc.), then over rows; irradiance ``Σ ω L``.
        """
        e = self.e[r0:r1, c0:c1]
        st, ct = self.sin_t[r0:r1], self.cos_t[r0:r1]
        v = np.array([st @ (e @ self.sin_p[c0:c1]), ct @ e.sum(axis=1),
                      -(st @ (e @ self.cos_p[c0:c1]))])
        if np.linalg.norm(v) <= 0:  # a black region: its geometric centre
            th = np.pi * (r0 + r1) / (2 * self.H)
            ph = np.pi * (c0 + c1) / self.W
            v = np.array([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)])
        om = self.omega_row[r0:r1]
        E = om @ self.img[r0:r1, c0:c1].sum(axis=1)
        return ExtractedLight(direction=v, irradiance=E, solid_angle=float(om.sum() * (c1 - c0)))


def _split(t: _Tables, reg: tuple[int, int, int, int], method: str
           ) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]] | None:
    """Split a region ``(r0, r1, c0, c1)`` in two, or None if it is a single pixel."""
    r0, r1, c0, c1 = reg
    h, w = r1 - r0, c1 - c0
    if h <= 1 and w <= 1:
        return None
    lat = np.pi / 2 - np.pi * (r0 + r1) / (2 * t.H)
    x_scale = np.cos(lat) * (2 * np.pi / t.W) / (np.pi / t.H)  # column step in row units
    split_cols = (w * x_scale >= h and w > 1) or h <= 1
    # per-slice sums along the split axis (slice k = column c0+k or row r0+k)
    if split_cols:
        idx = np.arange(c0, c1 + 1)

        def strip(S):
            return S[r1, idx] - S[r0, idx]
    else:
        idx = np.arange(r0, r1 + 1)

        def strip(S):
            return S[idx, c1] - S[idx, c0]

    s_e = _cumulative(t.e[r0:r1, c0:c1].sum(axis=0 if split_cols else 1))
    a_scale, b_scale = (x_scale, 1.0) if split_cols else (1.0, x_scale)
    if method == "variance":  # a = along the split axis, b = across it
        Er, Ec, Err, Ecc = t.moments
        along, across = ((Ec, Ecc), (Er, Err)) if split_cols else ((Er, Err), (Ec, Ecc))
        s_ea, s_eaa = (strip(S) for S in along)
        s_eb, s_ebb = (strip(S) for S in across)
    n = len(idx) - 1  # number of slices; cut k in 1..n-1 puts slices [0, k) left
    total = s_e[-1] - s_e[0]
    ks = np.arange(1, n)
    if method == "median_cut":
        if total > 0:
            left = s_e[ks] - s_e[0]
            k = int(ks[np.argmin(np.abs(left - total / 2))])
        else:
            k = n // 2
    elif method == "variance":

        def var(lo, hi):
            e = s_e[hi] - s_e[lo]
            ea, eaa = s_ea[hi] - s_ea[lo], s_eaa[hi] - s_eaa[lo]
            eb, ebb = s_eb[hi] - s_eb[lo], s_ebb[hi] - s_ebb[lo]
            safe = np.where(e > 0, e, 1.0)
            v = a_scale**2 * (eaa - ea**2 / safe) + b_scale**2 * (ebb - eb**2 / safe)
            return np.where(e > 0, v, 0.0)

        cost = var(0, ks) + var(ks, n)
        k = int(ks[np.argmin(cost)]) if total > 0 else n // 2
    else:
        raise ValueError(f"unknown extraction method {method!r}; use 'median_cut' or 'variance'")
    if split_cols:
        return (r0, r1, c0, c0 + k), (r0, r1, c0 + k, c1)
    return (r0, r0 + k, c0, c1), (r0 + k, r1, c0, c1)


def median_cut(image: np.ndarray, n_lights: int = 16, method: str = "median_cut"
               ) -> list[ExtractedLight]:
    """Split an equirect map ``(H, 2H, 3)`` into ``n_lights`` regions and return one light
    per region (see the module docstring for the rules), brightest first.

    Regions are split round by round (Debevec's ``2^k``); when ``n_lights`` is not a power
    of two the last round splits only the most energetic regions.
    """
    if n_lights < 1:
        raise ValueError(f"n_lights must be >= 1, got {n_lights}")
    t = _Tables(image)
    regions = [(0, t.H, 0, t.W)]
    while len(regions) < n_lights:
        need = n_lights - len(regions)
        order = sorted(range(len(regions)), key=lambda i: -t.energy(*regions[i]))
        chosen = set(order[:need])
        new: list[tuple[int, int, int, int]] = []
        progressed = False
        for i, reg in enumerate(regions):
            parts = _split(t, reg, method) if i in chosen else None
            if parts is None:
                new.append(reg)
            else:
                new.extend(parts)
                progressed = True
        regions = new
        if not progressed:
            break
    lights = [t.light(*reg) for reg in regions]
    lights.sort(key=lambda lt: -float(lt.irradiance @ LUMINANCE))
    return lights


def variance_minimisation(image: np.ndarray, n_lights: int = 16) -> list[ExtractedLight]:
    """Viriyothai & Debevec 2009 variance-minimisation sampling (see :func:`median_cut`)."""
    return median_cut(image, n_lights, method="variance")


def split_highlights(image: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Split a map into ``bright + rest`` by clipping luminance at ``threshold`` (radiance,
    W/(sr m^2)): ``rest = L min(1, threshold / Y(L))``, ``bright = L - rest``.

    The rest is continuous (a clipped copy of the map), so its low-order SH rings little;
    ``bright`` holds the light sources' energy above the threshold.
    """
    img = np.asarray(image, np.float64)
    lum = img[..., :3] @ LUMINANCE
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(lum > threshold, threshold / lum, 1.0)
    rest = img * f[..., None]
    return (img - rest).astype(np.float32), rest.astype(np.float32)


def luminance(image: np.ndarray) -> np.ndarray:
    """Luminance ``Y(L)`` (Rec. 709 weights) of an ``(H, W, >=3)`` map -> ``(H, W)`` float32
    (one map-sized float32 plane; no float64 copy of the map)."""
    img = np.asarray(image)[..., :3]
    return np.asarray(img @ LUMINANCE.astype(np.float32), dtype=np.float32)


def mean_luminance(lum: np.ndarray) -> float:
    """Solid-angle-weighted mean of an equirect luminance plane ``(H, W)`` (W/(sr m^2))."""
    H, W = lum.shape
    return float(equirect_row_solid_angle(H, W) @ lum.sum(axis=1, dtype=np.float64)
                 / (4 * np.pi))


def auto_threshold(image: np.ndarray, factor: float = 4.0,
                   lum: np.ndarray | None = None) -> float:
    """Default highlight threshold: ``factor`` x the solid-angle-weighted mean luminance.
    ``lum``: the map's :func:`luminance`, when the caller already has it."""
    return factor * mean_luminance(luminance(image) if lum is None else lum)


# ----------------------------------------------------------------------------- regions


def sphere_components(mask: np.ndarray, gap_px: int = 0) -> tuple[np.ndarray, int]:
    """Connected components of an equirect mask ``(H, W)`` *on the sphere*.

    8-connected in the image, plus: the longitude seam (column 0 touches column W-1, rows
    r-1..r+1), and each pole (every pixel of the top row touches every other one at +Y;
    the same for the bottom row at -Y). With ``gap_px > 0`` parts closer than ``gap_px``
    pixels (a disc, wrapped across the seam) are one component: the mask is dilated for
    the labelling only (on the slab of rows that holds the mask). Returns
    ``(labels (H, W), n)``: 0 off the mask, 1..n on it (uint16 when the labels cannot
    overflow it, else int32).
    """
    import cv2
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    mask = np.asarray(mask, bool)
    H, W = mask.shape
    g = min(max(int(gap_px), 0), W // 2)
    rows = np.flatnonzero(mask.any(axis=1))
    # 16-bit labels (half the memory of a 4k label plane) whenever they cannot overflow
    small = rows.size == 0 or int(np.count_nonzero(mask)) * (2 * g + 1) ** 2 < 65535
    labels = np.zeros((H, W), np.uint16 if small else np.int32)
    if rows.size == 0:
        return labels, 0
    # work on the slab of rows that holds the mask (and its gap): highlights are sparse
    r0, r1 = max(0, int(rows[0]) - g), min(H, int(rows[-1]) + 1 + g)
    m = np.ascontiguousarray(mask[r0:r1]).view(np.uint8)
    if g > 0:
        pad = np.concatenate([m[:, -g:], m, m[:, :g]], axis=1)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * g + 1, 2 * g + 1))
        m = np.ascontiguousarray(cv2.dilate(pad, kernel)[:, g:g + W])
        del pad
    n, slab = cv2.connectedComponents(m, connectivity=8,
                                      ltype=cv2.CV_16U if small else cv2.CV_32S)
    del m
    pairs = [np.zeros((0, 2), np.int64)]
    left, right = slab[:, 0].astype(np.int64), slab[:, -1].astype(np.int64)
    h = r1 - r0
    for shift in (-1, 0, 1):  # (r, 0) touches (r + shift, W - 1)
        a = left[max(0, -shift):h - max(0, shift)]
        b = right[max(0, shift):h + min(0, shift)]
        pairs.append(np.stack([a, b], axis=1))
    poles = ([slab[0]] if r0 == 0 else []) + ([slab[-1]] if r1 == H else [])
    for row in poles:  # all labels on a pole row meet at the pole
        ids = np.unique(row[row > 0]).astype(np.int64)
        if ids.size > 1:
            pairs.append(np.stack([ids[:-1], ids[1:]], axis=1))
    p = np.concatenate(pairs)
    p = p[(p[:, 0] > 0) & (p[:, 1] > 0)]
    graph = coo_matrix((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n, n))
    k, comp = connected_components(graph, directed=False)
    # component 0 is the background's; renumber the others 1..n'
    comp = comp.astype(np.int64)
    bg = comp[0]
    remap = np.where(comp == bg, 0, np.where(comp < bg, comp + 1, comp)).astype(labels.dtype)
    remap[0] = 0
    labels[r0:r1] = remap[slab] * mask[r0:r1]  # the gap's pixels are not ours
    return labels, int(k - 1)


@dataclass
class Highlights:
    """What :func:`highlight_regions` found.

    ``lights``: one light per kept region, most energetic first; ``dropped``: ``(H, W)``
    mask of the pixels of regions *not* made lights (too faint, too wide or over the cap:
    their energy belongs to the SH remainder), or None when none was dropped;
    ``regions``: number of regions found; ``energy``: luminance energy above the threshold
    in the whole map, ``sum Y(L - rest) Omega`` (W/m^2)."""

    lights: list[ExtractedLight]
    dropped: np.ndarray | None
    regions: int
    energy: float


def highlight_regions(image: np.ndarray, threshold: float, lum: np.ndarray | None = None,
                      max_lights: int = 16, gap_deg: float = 1.0, min_fraction: float = 0.01,
                      max_spread_deg: float = 45.0) -> Highlights:
    """The light sources of an equirect radiance map ``(H, 2H, 3)`` as lights.

    Pixels brighter than ``threshold`` (luminance, W/(sr m^2)) form regions on the sphere
    (:func:`sphere_components`: seam- and pole-aware; parts closer than ``gap_deg`` are one
    region, so a lamp seen through a grille or a sun split by a branch stays one light).
    Each region gives one light from the part of its radiance above the threshold (the
    :func:`split_highlights` rule, so lights + clipped remainder = the map): direction =
    energy centroid, irradiance = ``sum (L - rest) Omega``, ``solid_angle`` = its pixels' sr,
    ``spread`` = its angular radius. A compact source is therefore one light with all of
    its energy; an area source keeps its extent in ``solid_angle``/``spread``.

    The number of lights adapts: a region becomes a light if it holds at least
    ``min_fraction`` of the above-threshold energy and is no wider than
    ``max_spread_deg`` (wider glow is ambient, better in SH); at most ``max_lights``.
    Works on sparse pixel lists: memory is O(map luminance + highlight pixels).
    """
    img = np.asarray(image)[..., :3]
    H, W = img.shape[:2]
    lum = luminance(img) if lum is None else lum
    mask = lum > threshold
    gap_px = int(round(np.radians(max(gap_deg, 0.0)) * H / np.pi))
    labels, n = sphere_components(mask, gap_px)
    del mask
    if n == 0:
        return Highlights([], None, 0, 0.0)
    flat = labels.reshape(-1)
    idx = np.flatnonzero(flat)
    lab = flat[idx].astype(np.int64) - 1
    rows, cols = np.divmod(idx, W)
    lp = lum.reshape(-1)[idx].astype(np.float64)
    omega = equirect_row_solid_angle(H, W)[rows]
    w = omega * (1.0 - threshold / lp)  # Omega x the fraction of L above the threshold
    e = lp * w
    theta = (rows + 0.5) * (np.pi / H)
    phi = (cols + 0.5) * (2 * np.pi / W)
    st = np.sin(theta)
    E = np.bincount(lab, e, n)
    v = np.stack([np.bincount(lab, e * st * np.sin(phi), n),
                  np.bincount(lab, e * np.cos(theta), n),
                  -np.bincount(lab, e * st * np.cos(phi), n)], axis=1)
    rgb = img.reshape(-1, 3)[idx]
    irr = np.stack([np.bincount(lab, rgb[:, c] * w, n) for c in range(3)], axis=1)
    sa = np.bincount(lab, omega, n)
    norm = np.linalg.norm(v, axis=1)
    mean_cos = np.divide(norm, E, out=np.zeros(n), where=E > 0)
    spread = np.arccos(np.clip(2 * mean_cos - 1, -1.0, 1.0))
    total = float(E.sum())
    order = np.argsort(-E, kind="stable")
    keep = np.zeros(n, bool)
    for i in order:
        if keep.sum() >= max_lights:
            break
        if E[i] >= min_fraction * total and spread[i] <= np.radians(max_spread_deg):
            keep[i] = True
    lights = [ExtractedLight(direction=v[i], irradiance=irr[i], solid_angle=float(sa[i]),
                             spread=float(spread[i])) for i in order if keep[i]]
    dropped = None
    if not keep.all():
        lut = np.concatenate([[False], ~keep])
        dropped = lut[labels]
    return Highlights(lights, dropped, n, total)


# ----------------------------------------------------------------------------- Kan


def _label_blobs(mask: np.ndarray, wrap_columns: bool) -> np.ndarray:
    import cv2

    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if wrap_columns and n > 2:
        # merge components that touch across the longitude seam (u = 0 == u = 1)
        parent = list(range(n))

        def find(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        left, right = labels[:, 0], labels[:, -1]
        for a, b in zip(left, right, strict=True):
            if a and b:
                parent[find(a)] = find(b)
        labels = np.array([find(i) for i in range(n)])[labels]
    return labels


def brightest_blob(image: np.ndarray, directions: np.ndarray, solid_angle: np.ndarray,
                   threshold: float | None = None, rel_threshold: float = 0.2,
                   wrap_columns: bool = False) -> ExtractedLight | None:
    """Kan's light detection: threshold the luminance, label 8-connected blobs (OpenCV),
    keep the blob with the largest solid angle and return its light (direction = energy
    centroid of the blob on the sphere; irradiance = sum of ``L Omega`` over the blob).

    ``directions (H, W, 3)`` and ``solid_angle (H, W)`` describe the image's pixels (any
    mapping: equirect, fisheye, ...). The threshold defaults to ``rel_threshold`` x the
    maximum luminance (Kan does not give a value). Returns None when nothing is above it.
    """
    img = np.asarray(image, np.float64)[..., :3]
    lum = img @ LUMINANCE
    valid = solid_angle > 0
    if threshold is None:
        peak = lum[valid].max(initial=0.0)
        threshold = rel_threshold * peak
    mask = (lum > threshold) & valid
    if not mask.any():
        return None
    labels = _label_blobs(mask, wrap_columns)
    ids = labels[mask]
    areas = np.bincount(ids, weights=solid_angle[mask])
    areas[0] = 0.0
    best = int(np.argmax(areas))
    sel = labels == best
    w = lum[sel] * solid_angle[sel]
    v = (directions[sel] * w[:, None]).sum(axis=0)
    E = (img[sel] * solid_angle[sel][:, None]).sum(axis=0)
    return ExtractedLight(direction=v, irradiance=E, solid_angle=float(solid_angle[sel].sum()))
