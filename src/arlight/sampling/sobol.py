"""Owen-scrambled, shuffled Sobol points as Dr.Jit integer ops (Burley 2020).

Burley, *Practical Hash-based Owen Scrambling*, JCGT 9(4), 2020: a point of a
``D``-dimensional integrand is drawn from the first two Sobol dimensions (a (0,2)-sequence in
base 2) and padded to more dimensions by *shuffling*: every 2D (or 1D) set of dimensions
reads the sequence at an index that is itself Owen-scrambled with the set's own seed (Burley
§4, "shuffled scrambled Sobol"), and every coordinate is Owen-scrambled with its own seed
(§3). Each set is then a randomised (0, m, 2)-net for any power-of-two prefix of ``2^m``
samples, the sets are mutually decorrelated, and every point is uniformly distributed
(unbiased estimates). The nested uniform scramble is a hash of the bit-reversed value whose
bit ``k`` depends only on bits below ``k`` (Burley Listing 1, with N. Vegdahl's improved
Laine–Karras permutation, 2021).

Everything is a function of ``(seed, index, dimension)``: sample ``index`` of a pixel gets the
same numbers whatever pass draws it and in whatever order (the pass engine relies on this).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

# Joe & Kuo (2008) primitive polynomials of dimensions 1–3: (degree s, coefficients a,
# initial m_1..m_s)
_JOE_KUO = {1: (1, 0, (1,)), 2: (2, 1, (1, 3)), 3: (3, 1, (1, 3, 1))}


def direction_numbers(dim: int) -> list[int]:
    """The 32 direction numbers ``V_k`` (as 32-bit integers) of Sobol dimension ``dim``.

    Dimension 0 is the van der Corput sequence (``V_k = 2^(31−k)``); 1–3 follow the
    recurrence ``V_k = V_{k−s} ⊕ (V_{k−s} ≫ s) ⊕ ⊕_j a_j V_{k−j}`` (Bratley & Fox 1988) with
    Joe & Kuo's polynomials.
    """
    if dim == 0:
        return [1 << (31 - k) for k in range(32)]
    s, a, m = _JOE_KUO[dim]
    v = [m[k] << (31 - k) for k in range(s)]
    for k in range(s, 32):
        x = v[k - s] ^ (v[k - s] >> s)
        for j in range(1, s):
            if (a >> (s - 1 - j)) & 1:
                x ^= v[k - j]
        v.append(x)
    return v


_V = {d: direction_numbers(d) for d in range(4)}


def sobol_u32(index: mi.UInt32, dim: int) -> mi.UInt32:
    """Sobol coordinate ``dim`` (0–3) of points ``index`` as 32-bit fixed point."""
    if dim == 0:
        return dr.brev(index)
    x = dr.zeros(mi.UInt32, dr.width(index))
    for k, v in enumerate(_V[dim]):
        x ^= dr.select(((index >> k) & 1) != 0, mi.UInt32(v), mi.UInt32(0))
    return x


def hash_u32(x: mi.UInt32) -> mi.UInt32:
    """A 32-bit integer hash with full avalanche (``lowbias32``, C. Wellons 2018)."""
    x = mi.UInt32(x)
    x ^= x >> 16
    x *= 0x7FEB352D
    x ^= x >> 15
    x *= 0x846CA68B
    x ^= x >> 16
    return x


def hash_combine(seed: mi.UInt32, v) -> mi.UInt32:
    """A new well-mixed seed from ``seed`` and ``v`` (integer or UInt32)."""
    return hash_u32(mi.UInt32(seed) ^ hash_u32(mi.UInt32(v) + 0x9E3779B9))


def laine_karras(x: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """Vegdahl's Laine–Karras-style permutation: bit ``k`` of the result depends only on
    bits ``≤ k`` of ``x`` (a nested uniform scramble of the bit-reversed value)."""
    x = mi.UInt32(x)
    x ^= x * 0x3D20ADEA
    x += seed
    x *= (seed >> 16) | 1
    x ^= x * 0x05526C56
    x ^= x * 0x53A22864
    return x


def owen_scramble(x: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """Nested uniform (Owen) scramble of 32-bit fixed-point values (Burley Listing 1)."""
    return dr.brev(laine_karras(dr.brev(x), seed))


def sobol_2d(index: mi.UInt32, seed: mi.UInt32) -> mi.Point2f:
    """Shuffled, Owen-scrambled 2D Sobol point ``index`` for the dimension set of ``seed``.

    ``seed`` must already identify (pixel, replica, dimension set): distinct sets need
    distinct seeds. Values lie in ``[0, 1)``. (The first half of the 4D point.)
    """
    return sobol_4d_half(index, seed, 0)


def sobol_4d_half(index: mi.UInt32, seed: mi.UInt32, half: int) -> mi.Point2f:
    """Coordinates ``(0, 1)`` (``half = 0``) or ``(2, 3)`` (``half = 1``) of the shuffled,
    Owen-scrambled 4D Sobol point ``index`` of the dimension set ``seed``: two 2D sets read
    from one 4D point are stratified jointly (Burley §4 pads by 4D sets). Either half alone
    costs two Sobol dimensions."""
    i = owen_scramble(index, seed)
    d0, d1 = 2 * half, 2 * half + 1
    x = owen_scramble(sobol_u32(i, d0), hash_combine(seed, d0 + 1))
    y = owen_scramble(sobol_u32(i, d1), hash_combine(seed, d1 + 1))
    return mi.Point2f(to_unit(x), to_unit(y))


def sobol_1d(index: mi.UInt32, seed: mi.UInt32) -> mi.Float:
    """Shuffled, Owen-scrambled 1D Sobol (van der Corput) value ``index`` in ``[0, 1)``."""
    i = owen_scramble(index, seed)
    return to_unit(owen_scramble(dr.brev(i), hash_combine(seed, 1)))


def to_unit(x: mi.UInt32) -> mi.Float:
    """32-bit fixed point to a float in ``[0, 1)`` (the top 24 bits, never rounding to 1)."""
    return mi.Float(x >> 8) * (1.0 / (1 << 24))


__all__ = ["direction_numbers", "hash_combine", "hash_u32", "laine_karras", "owen_scramble",
           "sobol_1d", "sobol_2d", "sobol_4d_half", "sobol_u32", "to_unit"]
