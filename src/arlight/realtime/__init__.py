"""Building blocks shared by the rasterisation-class differential methods (``dlpv``, ``dir``,
``dvct``, ``ibl``, ``prt``, ``nearfield``). Engine tier: above :mod:`arlight.backend`, below
:mod:`arlight.methods`; blocks take small protocols or plain arrays, never a method's data
class (see ``docs/architecture.md``).

* :mod:`~arlight.realtime.light_reduction` — the world's lights as a few point, cosine
  (area-light patch), spot and directional lights plus an SH ambient remainder.
* :mod:`~arlight.realtime.gbuffer` — a ray-cast G-buffer (position, normal, albedo, role) and
  its per-pixel assembly into :class:`arlight.layers.Layers`.
* :mod:`~arlight.realtime.rsm` — reflective shadow maps per reduced light, for the mixed
  (``R_ρ``) and the real-only (``R_µ``) scene, and the prepared ``R_µ`` reuse (``RealMaps``).
* :mod:`~arlight.realtime.sh_volume` — 2-band RGB SH volumes: injection, Kaplanyan–Dachsbacher
  propagation, queries.
* :mod:`~arlight.realtime.voxels` — voxelisation and mip-mapped cone-tracing volumes (dvct).
* :mod:`~arlight.realtime.exact_sum` — order-independent fixed-point scatter sums.
* :mod:`~arlight.realtime.shading` — direct shading from reduced lights, spot falloff, bounds.
* :mod:`~arlight.realtime.ibl_shading` — image-based lighting: mip-mapped environments, GGX
  (the one ``D``/``G1``, also ``dvct``'s), per-shape specular tables.
* :mod:`~arlight.realtime.sog` — spherical-Gaussian fits of GGX lobes.
* :mod:`~arlight.realtime.oof` — AR object occlusion fields (Franke §5.2), the real-pixel
  relighting and the frame of ``ibl`` and ``prt`` (``render_layers``).
* :mod:`~arlight.realtime.prt_transfer` — precomputed radiance transfer (PRT, nearfield).
* :mod:`~arlight.realtime.prt_shading` — the virtual meshes' transfer and their per-frame
  PRT shading (``prt``, ``nearfield``).

The path-tracing engines (one-pass tracer, photons, dic's irradiance cache) live in
:mod:`arlight.tracing`.
"""
