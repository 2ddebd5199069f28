"""The metallic-roughness PBR material (``type = "pbr"``): its textures and their decoding.

One material that glTF 2.0's ``pbrMetallicRoughness`` and USD's ``UsdPreviewSurface`` both
map to (see ``docs/scene-format.md``, "PBR material"). Texture channels follow glTF:

* ``base_color_texture`` — sRGB-encoded RGB(A); the decoded RGB is multiplied by
  ``base_color``, the alpha channel (linear) by ``alpha``;
* ``metallic_roughness_texture`` — linear; **G** is roughness, **B** is metallic (multiplied by
  ``roughness`` and ``metallic``);
* ``normal_texture`` — linear tangent-space normals, ``n = 2·rgb − 1``, +Y up (OpenGL / glTF);
* ``occlusion_texture`` — linear, **R** channel;
* ``emissive_texture`` — sRGB-encoded RGB, multiplied by ``emissive`` (W/(sr·m²)).

A texture is decoded when the scene is loaded (:func:`decode_texture`), after its size has
been read from the file's header and checked against :data:`MAX_TEXTURE_PIXELS` — so a
huge texture fails before any memory is spent on it. Decoded pixels live in a
:class:`Texture`, which keeps the file (or the model-file reference) it came from.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError

MAX_TEXTURE_PIXELS = 4096 * 4096
"""Largest texture a scene may hold (pixels, 16.8 Mpx: 268 MB as float32 RGBA)."""
MAX_TEXTURE_BYTES_TOTAL = 1 << 30
"""Largest total of decoded texture memory (bytes, float32) one model may ask for."""

TEXTURE_FIELDS: dict[str, str] = {
    "base_color_texture": "srgb",
    "metallic_roughness_texture": "linear",
    "normal_texture": "linear",
    "occlusion_texture": "linear",
    "emissive_texture": "srgb",
}
"""PBR texture field -> how its RGB code values decode (``srgb`` or ``linear``; alpha is
always linear)."""


@dataclass(eq=False)
class Texture:
    """A decoded texture.

    Attributes:
        source: where it came from: a file path, or ``<model file>#<field>`` for a texture
            embedded in (or referenced by) a glTF/USD file.
        pixels: ``(H, W, C)`` float32, C = 3 or 4, values in [0, 1]: RGB decoded as the
            field says (sRGB → linear or as is), alpha as is. Row 0 is the top of the image
            (texture coordinate v = 0, glTF's and Mitsuba's convention).
    """

    source: str
    pixels: np.ndarray = field(repr=False)

    def __str__(self) -> str:
        return self.source


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB EOTF (IEC 61966-2-1) of code values in [0, 1]."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def image_size(data: bytes) -> tuple[int, int]:
    """(width, height) of an encoded PNG/JPEG image, read from its header only."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as im:
            return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError as exc:  # PIL's own bound (179 Mpx) is larger
        raise ValueError(f"texture is larger than the {MAX_TEXTURE_PIXELS / 1e6:.1f} Mpx "
                         f"allowed ({exc})") from exc


def decode_texture(data: bytes, encoding: str, source: str,
                   max_pixels: int = MAX_TEXTURE_PIXELS) -> Texture:
    """Decode an encoded LDR image (PNG, JPEG) for a PBR texture field.

    Args:
        data: the file's bytes.
        encoding: ``"srgb"`` (RGB sRGB-decoded) or ``"linear"`` (code values / max).
        source: where the bytes came from (kept in the texture, used in messages).
        max_pixels: the largest width × height accepted; checked on the header, before
            decoding.

    Raises:
        ValueError: unreadable data, a size over ``max_pixels``, or an empty image; the
            caller names the file and field.
    """
    from PIL import Image

    try:
        w, h = image_size(data)
    except ValueError:
        raise
    except Exception as exc:  # PIL raises many kinds for garbage
        raise ValueError(f"not a readable PNG/JPEG image ({exc})") from exc
    if w * h > max_pixels:
        raise ValueError(f"texture is {w}×{h} = {w * h / 1e6:.1f} Mpx, more than the "
                         f"{max_pixels / 1e6:.1f} Mpx allowed (it would take "
                         f"{w * h * 16 / 2**20:.0f} MiB decoded)")
    if w < 1 or h < 1:
        raise ValueError("empty image")
    with Image.open(io.BytesIO(data)) as im:
        mode = "RGBA" if im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info else "RGB"
        bits = 16 if im.mode.startswith("I;16") else 8
        arr = np.asarray(im.convert(mode), dtype=np.float64) / (2**bits - 1)
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if encoding == "srgb":
        arr[..., :3] = srgb_to_linear(arr[..., :3])
    return Texture(source, np.ascontiguousarray(arr, dtype=np.float32))


def read_texture_file(path: str | Path, encoding: str,
                      max_pixels: int = MAX_TEXTURE_PIXELS) -> Texture:
    """:func:`decode_texture` of a file (ValueError for a missing or bad file)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read {p} ({exc.strerror})") from exc
    return decode_texture(data, encoding, str(p), max_pixels)


def finish_pbr(fail: Callable[[str, str], InputError], params: dict[str, Any],
               field: str) -> dict[str, Any]:
    """A validated ``pbr`` parameter table with its texture paths decoded to :class:`Texture`.

    ``fail(field, message)`` builds the error (naming the scene file); textures given as
    :class:`Texture` (from a model file) are kept.
    """
    out = dict(params)
    for key, enc in TEXTURE_FIELDS.items():
        value = out.get(key)
        if isinstance(value, str):
            try:
                out[key] = read_texture_file(value, enc)
            except ValueError as exc:
                raise fail(f"{field}.{key}", f"{exc} ({value})") from exc
    if out["alpha_mode"] == "mask" and not 0.0 <= out["alpha_cutoff"] <= 1.0:
        raise fail(f"{field}.alpha_cutoff", f"must be in [0, 1], got {out['alpha_cutoff']}")
    warn_unrendered(out, field)
    return out


def warn_unrendered(params: dict[str, Any], where: str) -> None:
    """Warn (:class:`arlight.scene.models.ModelWarning`) about what the renderers do not
    draw yet: emission (``emissive`` > 0) — the object is rendered without it."""
    import warnings

    from arlight.scene.models.part import ModelWarning

    if max(params.get("emissive", [0.0])) > 0:
        warnings.warn(f"{where}: emissive: emission is not rendered yet (the object is shaded "
                      "without it)", ModelWarning, stacklevel=3)


def has_textures(params: dict[str, Any]) -> bool:
    """Whether a ``pbr`` material reads texture coordinates."""
    return any(params.get(k) is not None for k in TEXTURE_FIELDS)


def default_params() -> dict[str, Any]:
    """A ``pbr`` parameter table with every field at its default (canonical form), for
    model readers to fill in."""
    from arlight.scene.schema import MATERIAL_TYPES, Validator

    return Validator("<pbr>", Path.cwd()).fields({}, MATERIAL_TYPES["pbr"], "")


def check_factors(params: dict[str, Any], file: str, field: str) -> dict[str, Any]:
    """The non-texture fields of ``params`` validated against the schema (InputError naming
    ``file`` and ``field.<name>``); textures are passed through."""
    from arlight.scene.schema import MATERIAL_TYPES, Validator

    specs = {k: f for k, f in MATERIAL_TYPES["pbr"].items() if k not in TEXTURE_FIELDS}
    plain = {k: x for k, x in params.items() if k in specs}
    out = Validator(file, Path.cwd()).fields(plain, specs, field)
    return {**out, **{k: params.get(k) for k in TEXTURE_FIELDS}}
