"""The real proxy of a photographed table top, in the board's world frame (+Y up, the board
in ``Y = 0``; see :mod:`arlight.insert.registration`).

* the supporting plane: a rectangle over ``lo ≤ (X, Z) ≤ hi`` whose albedo texture's rows
  run along +Z and columns along +X (the plane's transform is
  :data:`arlight.insert.registration.WORLD_FROM_BOARD`, so texture row 0 lies at ``Z = lo``;
  two-sided, so its local normal pointing down does not matter);
* optional boxes (``--box X,Y,Z:SX,SY,SZ[:R,G,B]``: centre and full sizes in metres, board
  frame; albedo the plane's median unless given).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.insert.numbers import floats
from arlight.insert.registration import WORLD_FROM_BOARD


def plane_shape(lo: tuple[float, float], hi: tuple[float, float],
                material: dict[str, Any]) -> dict[str, Any]:
    """Scene table of the supporting plane ``Y = 0`` over ``lo ≤ (X, Z) ≤ hi`` (m)."""
    m = WORLD_FROM_BOARD.copy()
    m[:3, 3] = [(lo[0] + hi[0]) / 2, 0.0, (lo[1] + hi[1]) / 2]
    return {"name": "plane", "role": "real", "type": "rectangle",
            "size": [hi[0] - lo[0], hi[1] - lo[1]], "transform": {"matrix": m.tolist()},
            "material": material}


@dataclass(frozen=True)
class ProxyBox:
    """An axis-aligned real box: ``centre`` and full ``size`` (m, board frame), optional
    diffuse ``albedo`` (RGB in [0, 1]; None: the plane's median albedo)."""

    centre: tuple[float, float, float]
    size: tuple[float, float, float]
    albedo: tuple[float, float, float] | None = None

    def table(self, i: int, default_albedo: np.ndarray) -> dict[str, Any]:
        alb = default_albedo if self.albedo is None else np.asarray(self.albedo)
        return {"name": f"box{i}", "role": "real", "type": "box", "size": list(self.size),
                "transform": {"translate": list(self.centre)},
                "material": {"type": "diffuse", "albedo": np.asarray(alb, float).tolist()}}


def parse_box(spec: str, field: str = "--box") -> ProxyBox:
    """``X,Y,Z:SX,SY,SZ[:R,G,B]`` → :class:`ProxyBox` (InputError naming ``field``)."""
    parts = spec.split(":")
    if len(parts) not in (2, 3):
        raise InputError(f"cannot parse {spec!r}; expected X,Y,Z:SX,SY,SZ[:R,G,B]", field=field)
    centre = floats(parts[0], 3, field)
    size = floats(parts[1], 3, field)
    if min(size) <= 0:
        raise InputError(f"box sizes must be positive, got {parts[1]!r}", field=field)
    alb = floats(parts[2], 3, field, 0.0, 1.0) if len(parts) == 3 else None
    return ProxyBox(centre, size, alb)  # type: ignore[arg-type]
