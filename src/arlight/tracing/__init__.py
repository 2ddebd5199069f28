"""Path-tracing engines of the differential methods (tier above :mod:`arlight.backend`,
below :mod:`arlight.methods`; they know nothing of method options or ``Layers``).

* :mod:`~arlight.tracing.onepass` — the wavefront one-pass differential path tracer (Kán
  §3.3): its ray-type rules (hit rules 1–4, one-pass shadow visibility), light selection
  (:class:`~arlight.tracing.onepass.LightSelection`) and per-depth random dimensions of a
  :class:`~arlight.sampling.stream.LaneSampler`. Used by ``onepass`` and by ``dic``.
* :mod:`~arlight.tracing.photons` — photon maps for caustics (``onepass``'s ``caustics``).
* :mod:`~arlight.tracing.irradiance_cache` — dic's offline irradiance cache: records,
  placement and the splat geometry (Kán §4.2).
* :mod:`~arlight.tracing.irradiance_eval` — record irradiance through the one-pass tracer.
* :mod:`~arlight.tracing.irradiance_splat` — splatting records into the screen buffer.
* :mod:`~arlight.tracing.irradiance_shading` — dic's camera walk, on the one-pass rules.
* :mod:`~arlight.tracing.scenes` — :class:`~arlight.tracing.scenes.PathScenes`, the world
  and its µ/ρ Mitsuba views (the prepared state of ``reference``, ``onepass``, ``dic``).
"""
