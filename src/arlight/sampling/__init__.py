"""Sample generation: Owen-scrambled Sobol points (:mod:`.sobol`) and the per-lane samplers
of the path tracers (:mod:`.stream`).

Importing this package selects the Mitsuba variant (its types only exist once one is set).
"""

from arlight.jit import ensure_variant

VARIANT = ensure_variant()
