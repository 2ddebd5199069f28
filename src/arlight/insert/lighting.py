"""The real light of a photo, as scene lights in the board's world frame, and the
irradiance it puts on the supporting plane.

``--light`` takes one of (see ``docs/insert.md``):

* a ``LightEstimate`` JSON (``arlight light estimate``; ARCore/ARKit/WebXR layouts too):
  its main light becomes a ``directional`` light and its SH remainder an ``sh`` light;
* an HDR panorama (``.hdr``/``.exr``, equirect in the conventions' mapping) used as an
  ``envmap`` light;
* a manual rig: inline ``sun:DX,DY,DZ:E[:AMBIENT]`` (direction *towards* the sun in board
  coordinates, irradiance E in W/m² on a surface facing it, optional uniform ambient
  radiance in W/(sr·m²)) or a ``.toml`` file with ``[[sun]]`` (``direction``,
  ``irradiance``), ``[[spot]]`` (``position``, ``target``, ``intensity``, ``cutoff_deg``,
  ``beam_width_deg``) tables and ``ambient``.

``rotation_deg`` turns a panorama or an estimate about +Y (right-handed, counter-clockwise
seen from above, as an ``envmap`` light's ``rotation_deg``): the angle between the
panorama's frame and the board's.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.scene.model import Light
from arlight.scene.schema import LIGHT_TYPES, REQUIRED, Field, Validator

HDR_SUFFIXES = (".hdr", ".exr")


def _rgb(x: Any, what: str, field: str) -> list[float]:
    a = np.asarray(x, np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3 or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InputError(f"{what} must be a finite number >= 0 or three of them, got {x!r}",
                         field=field)
    return a.tolist()


def _vec3(x: Any, what: str, field: str, nonzero: bool = True) -> np.ndarray:
    a = np.asarray(x, np.float64).reshape(-1)
    if a.size != 3 or not np.all(np.isfinite(a)) or (nonzero and not np.any(a)):
        raise InputError(f"{what} must be three finite numbers"
                         f"{', not all zero' if nonzero else ''}, got {x!r}", field=field)
    return a


def _rotate_y(v: np.ndarray, deg: float) -> np.ndarray:
    """Rotate about +Y, right-handed (takes +X to −Z at 90°), as ``rotate = [0, 1, 0, deg]``."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def sun_lights(direction_to_sun: Any, irradiance: Any, ambient: Any = 0.0,
               field: str = "--light") -> list[dict[str, Any]]:
    """Scene-light tables of a sun (directional light arriving *from* ``direction_to_sun``,
    world = board frame, +Y up; ``irradiance`` W/m² on a surface facing it) plus a uniform
    ``ambient`` sky radiance (W/(sr·m²); omitted when 0)."""
    d = _vec3(direction_to_sun, "the sun direction", field)
    out: list[dict[str, Any]] = [{"type": "directional",
                                  "direction": (-d / np.linalg.norm(d)).tolist(),
                                  "irradiance": _rgb(irradiance, "the sun irradiance", field)}]
    amb = _rgb(ambient, "the ambient radiance", field)
    if any(amb):
        out.append({"type": "constant", "radiance": amb})
    return out


def _parse_inline_sun(spec: str) -> list[dict[str, Any]]:
    parts = spec.split(":")
    if len(parts) not in (3, 4):
        raise InputError(f"cannot parse {spec!r}; expected sun:DX,DY,DZ:IRRADIANCE[:AMBIENT]",
                         field="--light")
    try:
        d = [float(x) for x in parts[1].split(",")]
        e = float(parts[2])
        amb = float(parts[3]) if len(parts) == 4 else 0.0
    except ValueError as exc:
        raise InputError(f"cannot parse {spec!r} ({exc})", field="--light") from exc
    return sun_lights(d, e, amb)


SUN_FIELDS: dict[str, Field] = {
    "direction": Field("vec3", REQUIRED, "direction *towards* the sun (board frame, +Y up)"),
    "irradiance": Field("rgb", REQUIRED, "on a surface facing the sun", "W/m²", min=0.0),
}
RIG_FIELDS: dict[str, Field] = {
    "sun": Field("table", [], "one `[sun]` table or a list of `[[sun]]` tables"),
    "spot": Field("table", [], "`[[spot]]` tables, the fields of a scene's `spot` light"),
    "ambient": Field("rgb", 0.0, "uniform sky radiance", "W/(sr·m²)", min=0.0),
}
"""The fields of a ``--light`` rig file (``.toml``), read by the schema ``Validator``; a spot
has the fields of a scene's ``spot`` light (:data:`arlight.scene.schema.LIGHT_TYPES`)."""


def _tables(v: Validator, value: Any, field: str, one_allowed: bool = False) -> list[dict]:
    if one_allowed and isinstance(value, dict):
        return [value]
    if not isinstance(value, list):
        raise v.fail(field, f"expected a list of tables, got {type(value).__name__}")
    return [v.table(x, f"{field}[{i}]") for i, x in enumerate(value)]


def _rig_from_toml(path: Path) -> list[dict[str, Any]]:
    src = str(path)
    try:
        d = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"cannot read the light rig ({exc})", file=src) from exc
    v = Validator(src, path.parent)
    rig = v.fields(d, RIG_FIELDS, "")
    out: list[dict[str, Any]] = []
    for i, s in enumerate(_tables(v, rig["sun"], "sun", one_allowed=True)):
        sun = v.fields(s, SUN_FIELDS, f"sun[{i}]")
        if not any(sun["direction"]):
            raise v.fail(f"sun[{i}].direction", "must not be zero")
        out += sun_lights(sun["direction"], sun["irradiance"], 0.0, f"sun[{i}]")
    for i, s in enumerate(_tables(v, rig["spot"], "spot")):
        out.append({"type": "spot", **v.fields(s, LIGHT_TYPES["spot"], f"spot[{i}]")})
    if any(rig["ambient"]):
        out.append({"type": "constant", "radiance": rig["ambient"]})
    if not out:
        raise InputError("the rig has no light (give [[sun]], [[spot]] or ambient)", file=src)
    return out


def light_tables(spec: str, rotation_deg: float = 0.0, scale: float = 1.0) -> list[dict]:
    """Scene-light tables (schema of ``arlight.scene``) for a ``--light`` value.

    ``rotation_deg`` turns panoramas and estimates about +Y; ``scale`` multiplies every
    light's radiance, irradiance or intensity (an exposure correction between the light
    capture and the photo). Raises :class:`InputError` naming the file for an unreadable or
    malformed light."""
    if not (np.isfinite(rotation_deg) and np.isfinite(scale) and scale >= 0):
        raise InputError("rotation and scale must be finite (scale >= 0)", field="--light")
    if spec.lower().startswith("sun:"):
        tables = _parse_inline_sun(spec)
    else:
        path = Path(spec)
        if not path.is_file():
            raise InputError("light file not found", file=spec, field="--light")
        suffix = path.suffix.lower()
        if suffix in HDR_SUFFIXES:
            tables = [{"type": "envmap", "file": str(path.resolve()), "mapping": "equirect",
                       "rotation_deg": float(rotation_deg)}]
        elif suffix == ".toml":
            tables = _rig_from_toml(path)
        elif suffix == ".json":
            from arlight.light.estimate import LightEstimate

            try:
                est = LightEstimate.load(path)
            except ValueError as exc:
                raise InputError(f"not a light estimate ({exc})", file=spec,
                                 field="--light") from exc
            tables = est.to_scene_lights("directional")
            for t in tables:
                if t["type"] == "directional":
                    t["direction"] = _rotate_y(np.asarray(t["direction"]), rotation_deg).tolist()
                elif t["type"] == "sh":
                    t["rotation_deg"] = float(rotation_deg)
        else:
            raise InputError("unknown light file type; expected a LightEstimate .json, an HDR "
                             "panorama (.hdr/.exr) or a rig (.toml)", file=spec, field="--light")
    if scale != 1.0:
        for t in tables:
            for k in ("radiance", "irradiance", "intensity"):
                if k in t:
                    t[k] = (np.asarray(t[k], np.float64) * scale).tolist()
            if t["type"] in ("envmap", "sh"):
                t["scale"] = float(t.get("scale", 1.0)) * scale
    return tables


def _row_cosine_weights(height: int, width: int) -> np.ndarray:
    """``∫ max(0, cos θ) dω`` over each pixel of an equirect row ``(H,)`` (sr), exact for a
    radiance constant within the pixel: ``(2π/W)·(sin²θ₁ − sin²θ₀)/2`` above the horizon."""
    t = np.linspace(0.0, np.pi, height + 1)
    t = np.minimum(t, np.pi / 2)
    return (np.sin(t[1:]) ** 2 - np.sin(t[:-1]) ** 2) / 2 * (2 * np.pi / width)


def plane_irradiance(lights: list[Light], points: np.ndarray) -> np.ndarray:
    """Irradiance (W/m², RGB) on the upward face (+Y normal) of the horizontal plane at world
    ``points (N, 3)``, from the scene's lights, unoccluded. Environment lights (``envmap``,
    ``sh``, ``constant``) integrate the upper hemisphere (independent of their rotation
    about +Y); ``directional`` gives ``E·max(0, cos)``; ``point``, ``sphere`` and ``spot``
    ``I·cos/r²`` (a spot's fall-off linear in angle between ``beam_width_deg`` and
    ``cutoff_deg``). ``area`` lights are not supported (ValueError)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    E = np.zeros((len(p), 3))
    for lt in lights:
        q = lt.params
        if lt.type == "constant":
            E += np.pi * np.asarray(q["radiance"])
        elif lt.type in ("envmap", "sh"):
            m = np.asarray(lt.radiance_map, np.float64)
            w = _row_cosine_weights(m.shape[0], m.shape[1])
            E += q.get("scale", 1.0) * np.einsum("hwc,h->c", m, w)
        elif lt.type == "directional":
            d = np.asarray(q["direction"], np.float64)
            E += max(0.0, -d[1] / np.linalg.norm(d)) * np.asarray(q["irradiance"])
        elif lt.type in ("point", "sphere", "spot"):
            v = np.asarray(q["position"], np.float64) - p
            r = np.linalg.norm(v, axis=1)
            f = np.clip(v[:, 1], 0, None) / r**3
            if lt.type == "spot":
                axis = np.asarray(q["target"], np.float64) - np.asarray(q["position"])
                axis /= np.linalg.norm(axis)
                ang = np.degrees(np.arccos(np.clip((-v / r[:, None]) @ axis, -1, 1)))
                cut, beam = q["cutoff_deg"], q["beam_width_deg"]
                f *= np.clip((cut - ang) / max(cut - beam, 1e-9), 0, 1)
            E += f[:, None] * np.asarray(q["intensity"])[None]
        else:
            raise ValueError(f"plane_irradiance: {lt.type} lights are not supported")
    return E
