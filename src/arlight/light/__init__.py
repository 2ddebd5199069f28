"""Light estimation: spherical harmonics, environment maps and their mappings, fisheye
cameras, importance sampling, light extraction and the :class:`LightEstimate` exchange type.

Modules: :mod:`~arlight.light.sh`, :mod:`~arlight.light.envmap`,
:mod:`~arlight.light.fisheye`, :mod:`~arlight.light.sampling`,
:mod:`~arlight.light.extract`, :mod:`~arlight.light.estimate`, :mod:`~arlight.light.cli`.
See ``docs/light.md``.
"""
