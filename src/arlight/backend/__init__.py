"""Mitsuba 3 backend: variant selection, scene building (real-only µ and mixed ρ views),
camera ray generation and batched ray queries.

Importing this package selects the Mitsuba variant (see :mod:`arlight.jit`),
because Mitsuba's types only exist once a variant is set.
"""

from arlight.jit import ensure_variant

VARIANT = ensure_variant()
