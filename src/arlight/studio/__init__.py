"""arlight studio: a live, interactive AR composite in the browser (``arlight studio``).

A local web server (:mod:`arlight.studio.server`, aiohttp) serves one page
(``static/``) and streams composites over a WebSocket
(:mod:`arlight.studio.protocol`); :mod:`arlight.studio.engine` prepares each method once
and renders the session's poses per frame on one worker thread, latest-wins;
:mod:`arlight.studio.picking` answers the pointer's ray queries against the proxy;
:mod:`arlight.studio.pose` is a dragged object's placement. See ``docs/studio.md``.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Engine", "StudioConfig"]


def __getattr__(name: str) -> Any:  # lazy: `arlight --help` does not load the engine
    if name in __all__:
        from arlight.studio import engine

        return getattr(engine, name)
    raise AttributeError(name)
