"""Functions on the unit sphere, below both the scene and the light packages.

* :mod:`~arlight.sphere.sh` — real spherical harmonics: basis, projection, rotation,
  irradiance, triple products (Franke Eq. 4.4–4.7).
* :mod:`~arlight.sphere.envmap` — environment-map mappings (equirectangular, angular,
  mirror ball, fisheye) and conversions between them.
* :mod:`~arlight.sphere.fisheye` — the fisheye camera model those mappings use.
* :mod:`~arlight.sphere.points` — point sets (spherical Fibonacci).

The scene loader (SH and angular-map lights) and light estimation both build on these; this
package imports neither of them. Conventions: ``docs/conventions.md``.
"""
