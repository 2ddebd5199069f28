"""The camera→texel projection cached per rig and proxy (issue #32; Rohmer §4.1).

Which texels a fisheye camera sees, with what weight ``w_i = cos α_i · cos β_i`` and at which
pixels, depends on the rig (every camera's intrinsics, orientation and centre) and on the
proxy (its triangles and the atlas laid over them: resolution and supersampling) — never on
the images. :class:`ProjectionCache` keeps those :class:`~arlight.nearfield.projection.
CameraTaps` under a content hash of exactly these inputs (:func:`proxy_key`,
:func:`rig_key`, :func:`arlight.content_hash.content_hash`), so a server update only samples
the new images at the cached taps. A camera moved or recalibrated, a camera added or
dropped, a real shape moved or the atlas laid out anew gives another key: the taps are
computed again (a key, not an object's identity: an equal rig built anew hits the cache).

The cache is small (:data:`CAPACITY` entries, least recently used dropped). An entry holds
per camera 8 B per covered texel (the weights) and 56 B per texel it sees (index, four tap
indices, two fractions): a rig of 6 cameras over a 128² atlas (5770 texels) ≈ 1 MB, over
Rohmer's 1024² atlas (573 000 texels) ≈ 100 MB (measured on the cornell proxy).
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import PurePath
from typing import Any

import numpy as np

from arlight.content_hash import content_hash
from arlight.nearfield.projection import CameraTaps

CAPACITY = 2
"""Rig / proxy combinations kept (a server alternating between two rigs does not thrash;
more would hold ≈ 100 MB each at a 1024² atlas)."""

RIG_IGNORED_FIELDS = frozenset({"image"})
"""Rig camera fields that do not change the projection (the path of its image)."""


def _plain(value: Any) -> Any:
    """``value`` as plain data for :func:`content_hash`: dataclasses (camera models) by type
    name and fields; sequences item by item; arrays, numbers and strings as they are."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return [type(value).__name__,
                {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                 if f.name not in RIG_IGNORED_FIELDS}]
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, np.ndarray):
        return np.ascontiguousarray(value)
    return value


def rig_key(cameras: Sequence[Any]) -> str:
    """Content hash of a rig: every camera's name, model (intrinsics, distortion, size, field
    of view, orientation) and centre, in rig order."""
    return content_hash(_plain(list(cameras)), length=32)


def proxy_key(vertices: np.ndarray, faces: np.ndarray, atlas_resolution: int,
              supersample: int) -> str:
    """Content hash of the proxy as the projection sees it: its world-space triangles
    (vertices in m, faces) and the atlas settings that place the texels on them."""
    return content_hash(np.asarray(vertices, np.float64), np.asarray(faces, np.int64),
                        int(atlas_resolution), int(supersample), length=32)


class ProjectionCache:
    """Camera taps per key (module docstring), least recently used dropped beyond
    ``capacity``.

    Attributes:
        hits: lookups answered from the cache.
        misses: lookups that computed the taps.
    """

    def __init__(self, capacity: int = CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self._entries: OrderedDict[str, list[CameraTaps]] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: str) -> bool:
        return key in self._entries

    def get(self, key: str, build: Callable[[], list[CameraTaps]]) -> list[CameraTaps]:
        """The taps stored under ``key``, or ``build()``'s (stored; nothing is stored when
        it raises)."""
        taps = self._entries.get(key)
        if taps is not None:
            self.hits += 1
            self._entries.move_to_end(key)
            return taps
        self.misses += 1
        taps = build()
        self._entries[key] = taps
        while len(self._entries) > self.capacity:
            self._entries.popitem(last=False)
        return taps

    def clear(self) -> None:
        """Drop every entry (the counters stay)."""
        self._entries.clear()


__all__ = ["CAPACITY", "ProjectionCache", "proxy_key", "rig_key"]
