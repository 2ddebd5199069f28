"""A :class:`NearFieldLight` as a JSON file (``arlight light atlas -o vals.json``; the
``nearfield`` method's ``light`` option). The network format belongs to
``arlight.lightserver``; this is the file form::

    {"format": "arlight-nearfield/1", "sequence": 3, "timestamp": 1.7e9,
     "vals": [{"position": [x, y, z], "normal": [...], "intensity": [r, g, b],
               "area": a}, ...],                     # m, unit, W/sr, m²
     "sh": [[[c00r, c00g, c00b], ... 9 rows], ...],  # per virtual object, W/(sr·m²)
     "objects": ["bunny", ...]}                      # names, in the order of "sh"
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arlight.errors import InputError, read_text
from arlight.io.images import atomic_write
from arlight.nearfield.state import NearFieldLight

FORMAT = "arlight-nearfield/1"


def light_to_dict(light: NearFieldLight, objects: list[str] | None = None) -> dict:
    """The JSON-ready dict of ``light`` (module docstring)."""
    return {
        "format": FORMAT, "sequence": int(light.sequence), "timestamp": float(light.timestamp),
        "vals": [{"position": p.tolist(), "normal": n.tolist(), "intensity": i.tolist(),
                  "area": float(a)} for p, n, i, a in zip(light.positions, light.normals,
                                                          light.intensity, light.area,
                                                          strict=True)],
        "sh": light.sh.tolist(),
        "objects": list(objects or []),
    }


def save_light(light: NearFieldLight, path: str | Path, objects: list[str] | None = None
               ) -> Path:
    """Write ``light`` atomically (nothing is left behind on failure)."""
    path = Path(path)
    with atomic_write(path, ".json") as tmp:
        tmp.write_text(json.dumps(light_to_dict(light, objects), indent=1))
    return path


def load_light(path: str | Path) -> NearFieldLight:
    """Read a light file. Raises InputError naming the file and field."""
    path = Path(path)
    try:
        d = json.loads(read_text(path, "light file"))
    except json.JSONDecodeError as exc:
        raise InputError(f"cannot read the light file ({exc})", file=str(path)) from exc
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise InputError(f"not a near-field light file (format must be {FORMAT!r})",
                         file=str(path), field="format")
    try:
        vals = d["vals"]
        m = len(vals)

        def col(key: str, shape: tuple) -> np.ndarray:
            return np.asarray([v[key] for v in vals], np.float64).reshape((m, *shape))

        return NearFieldLight(col("position", (3,)), col("normal", (3,)),
                              col("intensity", (3,)), col("area", ()),
                              np.asarray(d.get("sh", []), np.float64).reshape(-1, 9, 3),
                              int(d.get("sequence", 0)), float(d.get("timestamp", 0.0)))
    except InputError:
        raise
    except Exception as exc:  # KeyError, TypeError, ValueError, ArlightError
        raise InputError(f"bad light data ({exc})", file=str(path), field="vals") from exc


__all__ = ["FORMAT", "light_to_dict", "load_light", "save_light"]
