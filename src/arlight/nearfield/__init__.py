"""Near-field light from several HDR fisheye cameras (Rohmer et al., TVCG 2015).

A radiance atlas over the real proxy, split into direct and indirect parts; the direct part
compressed into a few virtual area lights (VALs), the indirect part into 9 SH coefficients
per virtual object. :class:`NearFieldLight` is what the server computes and what a client
renders with (``arlight.lightserver`` carries it over the network).

Server: :class:`arlight.nearfield.pipeline.NearFieldServer` (``atlas``, ``projection``,
``split``, ``vals``, ``cubemap``, ``indirect``); rig: :mod:`arlight.nearfield.cameras`;
synthetic fisheye images: :mod:`arlight.nearfield.capture`; client shading:
:mod:`arlight.nearfield.client` behind the ``nearfield`` method and
:class:`arlight.methods.nearfield.NearFieldClient`. See ``docs/methods/nearfield.md``.
"""

from arlight.nearfield.state import NearFieldLight

__all__ = ["NearFieldLight"]
