"""Real-time building blocks shared by the interactive differential methods.

* :mod:`~arlight.realtime.light_reduction` — the world's lights as a few point, cosine
  (area-light patch), spot and directional lights plus an SH ambient remainder.
* :mod:`~arlight.realtime.gbuffer` — a ray-cast G-buffer (position, normal, albedo, role).
* :mod:`~arlight.realtime.rsm` — reflective shadow maps per reduced light, for the mixed
  (``R_ρ``) and the real-only (``R_µ``) scene.
* :mod:`~arlight.realtime.sh_volume` — 2-band (4-coefficient) RGB SH volumes: injection,
  Kaplanyan–Dachsbacher propagation (Dr.Jit and a NumPy peer), queries.

Used by ``dlpv`` (Franke 2013) and ``dir`` (Knecht et al. 2010); see ``docs/methods/dlpv.md``.
"""
