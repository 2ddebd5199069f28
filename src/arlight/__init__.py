"""arlight: photorealistic augmented reality on Mitsuba 3.

Virtual objects are inserted into real camera frames with the real light on them, and the
real scene is relit for them through differential rendering (Debevec 1998; Kán 2014 Eq. 2.20).
See ``docs/`` for the scene format and conventions.
"""

__version__ = "0.1.0"
