"""Virtual objects as AR ships them: glTF 2.0 / GLB and USD / USDZ files with PBR materials.

:func:`read_model` reads a model file into :class:`ModelPart` s — triangle meshes in the
model's world space (metres, right-handed, +Y up: arlight's world; see
``docs/scene-format.md``) with ``pbr`` material tables — and runs the checks every format
shares. Errors are :class:`arlight.errors.InputError` naming the model file and the field
inside it; what is loaded only partly (animation, skinning, morph targets) is a
:class:`ModelWarning`.
"""

from __future__ import annotations

from pathlib import Path

from arlight.errors import InputError
from arlight.scene.models.part import Model, ModelError, ModelPart, ModelWarning, check_model

GLTF_SUFFIXES = (".gltf", ".glb")
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
MODEL_SUFFIXES = GLTF_SUFFIXES + USD_SUFFIXES
"""File suffixes :func:`read_model` reads."""


def is_model_path(path: str | Path) -> bool:
    """Whether ``path`` names a glTF or USD file (by its suffix)."""
    return Path(path).suffix.lower() in MODEL_SUFFIXES


def read_model(path: str | Path, select: str | None = None) -> Model:
    """Read a glTF/GLB or USD/USDZ file into parts (world space, metres, +Y up).

    Args:
        path: the model file.
        select: a glTF node name or a USD prim path; only it and what lies below it are
            read (None: the whole default scene).

    Raises:
        InputError: ``<file>: <field inside the file>: <what is wrong>`` for a missing or
            unreadable file, an unsupported extension, missing textures, degenerate
            geometry, an absurd scale or too large textures.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in MODEL_SUFFIXES:
        raise InputError(f"unsupported model format {suffix!r}; expected one of "
                         f"{', '.join(MODEL_SUFFIXES)}", file=str(p))
    if not p.is_file():
        raise InputError("model file not found", file=str(p))
    try:
        if suffix in GLTF_SUFFIXES:
            from arlight.scene.models.gltf import read_gltf

            model = read_gltf(p, select)
        else:
            from arlight.scene.models.usd import read_usd

            model = read_usd(p, select)
        check_model(model)
    except ModelError as exc:
        raise InputError(exc.message, file=str(p), field=exc.field) from exc
    except InputError:
        raise
    except Exception as exc:  # the parsers raise many kinds for garbage
        text = " ".join(str(exc).split())  # parsers' messages span lines
        raise InputError(f"cannot read the model ({type(exc).__name__}: {text})",
                         file=str(p)) from exc
    return model


__all__ = ["GLTF_SUFFIXES", "MODEL_SUFFIXES", "USD_SUFFIXES", "Model", "ModelError",
           "ModelPart", "ModelWarning", "is_model_path", "read_model"]
