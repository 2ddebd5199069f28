"""arlight: photorealistic augmented reality on Mitsuba 3.

Virtual objects are inserted into real camera frames with the real light on them, and the
real scene is relit for them through differential rendering (Debevec 1998; Kán 2014 Eq. 2.20).
See ``docs/`` for the scene format and conventions.

Importing arlight before NumPy (as the ``arlight`` command does) loads OpenBLAS with one
thread unless ``OPENBLAS_NUM_THREADS`` is set: Dr.Jit's pool already uses every core, and
OpenBLAS' own pool, waking for the small per-frame products of the methods, cost ~15 ms a
frame on a loaded 2-core machine (issue #32) and 7× the CPU time in least-squares fits
(tests/conftest.py). Set the variable to another value to choose otherwise.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
