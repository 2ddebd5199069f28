"""Light estimation: importance sampling, light extraction and the :class:`LightEstimate`
exchange type, on top of the sphere maths in :mod:`arlight.sphere` (spherical harmonics,
environment-map mappings, fisheye cameras).

Modules: :mod:`~arlight.light.sampling`, :mod:`~arlight.light.extract`,
:mod:`~arlight.light.estimate`, :mod:`~arlight.light.cli`.
See ``docs/light.md``.
"""
