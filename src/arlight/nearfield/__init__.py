"""Near-field light from several HDR fisheye cameras (Rohmer et al., TVCG 2015).

A radiance atlas over the real proxy, split into direct and indirect parts; the direct part
compressed into a few virtual area lights (VALs), the indirect part into 9 SH coefficients
per virtual object. :class:`NearFieldLight` is what the server computes and what a client
renders with (``arlight.lightserver`` carries it over the network).

Server: :class:`arlight.nearfield.pipeline.NearFieldServer` (``atlas``, ``projection``,
``split``, ``vals``, ``cubemap``, ``indirect``); rig: :mod:`arlight.nearfield.cameras`;
synthetic fisheye images: :mod:`arlight.nearfield.capture`; client shading:
:mod:`arlight.nearfield.shading` behind the ``nearfield`` method and
:class:`arlight.methods.nearfield.NearFieldClient`. See ``docs/methods/nearfield.md``.
"""



def __getattr__(name: str):
    """:class:`NearFieldLight`, imported on first use (``import arlight.cli`` mounts
    ``light atlas`` without loading numpy)."""
    if name == "NearFieldLight":
        from arlight.nearfield.state import NearFieldLight

        return NearFieldLight
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["NearFieldLight"]
