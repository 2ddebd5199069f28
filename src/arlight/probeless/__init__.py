"""Probeless photometric registration from RGB-D (Gruber et al., IEEE VR 2014).

* :mod:`~arlight.probeless.directions` — the 81 world-fixed directions, interleaved subsets
* :mod:`~arlight.probeless.transfer` — batched 10 cm visibility, transfer vectors (E3)
* :mod:`~arlight.probeless.estimate` — least-squares SH light, conditioning (E5, E8)
* :mod:`~arlight.probeless.pipeline` — per-frame pipeline, variants RM/REG/ART, caches,
  SH differential shading (E7)
* :mod:`~arlight.probeless.reconstruct` — Open3D TSDF reconstruction of RGB-D frames
* :mod:`~arlight.probeless.rgbd_io` — reading RGB-D folders and poses
* :mod:`~arlight.probeless.synthetic_rgbd` — synthetic sequences with known light
* :mod:`~arlight.probeless.cli` — ``arlight light probeless``

The method ``probeless`` (:mod:`arlight.methods.probeless`) renders single frames with it.
See ``docs/methods/probeless.md``.
"""
