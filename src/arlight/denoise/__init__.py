"""Denoised differential rendering (issue #31): Intel Open Image Denoise on what a Monte
Carlo method rendered, never on the photograph.

* :mod:`~arlight.denoise.options` — the ``denoise*`` method options and
  :class:`~arlight.denoise.options.DenoiseSettings` (pure data; the method contract adds
  the options to every method whose capabilities say ``noisy``).
* :mod:`~arlight.denoise.oidn` — OIDN's ``RT`` filter on the CPU (``pyoidn`` wheel).
* :mod:`~arlight.denoise.aux` — clean first-hit albedo and normal from a camera-ray pass
  through the mixed Mitsuba scene (first non-specular hit behind mirrors and glass).
* :mod:`~arlight.denoise.differential` — the insertion's footprint and the denoised layers
  composited onto the untouched frame; the raw layers stay in ``DenoisedLayers.noisy``.
* :mod:`~arlight.denoise.bias` — signed error of a result against the ground truth in
  shadows, on the virtual object and at its silhouette.

Engine tier (imports core and backend). Importing the package loads neither Mitsuba nor
OIDN; ``aux`` loads Mitsuba, ``oidn`` loads OIDN on first use.

See ``docs/methods/denoising.md``.
"""

from arlight.denoise.options import NAMES, OPTIONS, DenoiseSettings

__all__ = ["DenoiseSettings", "NAMES", "OPTIONS"]
