"""Writing a method's layers: EXR for every HDR layer, PNG for display.

The display PNG uses the scene's transfer function (:class:`arlight.camera_response.Transfer`), the
exact inverse of the decoding applied to the input frame, so an unchanged frame comes out
byte-identical. The bit depth follows the input frame (8 or 16 bits; 8 for HDR frames).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arlight.io.images import atomic_write, write_exr, write_png
from arlight.methods.base import Layers
from arlight.scene.model import ARScene


def display_dtype(scene: ARScene) -> type:
    """uint16 when the frame came from a 16-bit file, else uint8."""
    codes = scene.frame_codes
    return np.uint16 if codes is not None and codes.dtype == np.uint16 else np.uint8


LAYER_FILES = ("*.exr", "composite.png", "stats.json", "progressive_*.png", "error.csv",
               "error.png")
"""Names of the files a render writes (an existing folder of only these may be replaced)."""


def write_layers(layers: Layers, scene: ARScene, out_dir: str | Path) -> dict[str, Path]:
    """Write ``composite.png`` and EXRs of every layer as the folder ``out_dir``; return the
    paths.

    Files: ``composite.exr``, ``composite.png``, ``mixed.exr``, ``delta.exr``, ``mask.exr``,
    ``real.exr`` (when the method has it), ``stderr_<layer>.exr`` and ``stats.json``
    (``seconds``, ``time_<stage>`` seconds, counters). Denoised layers (``denoise = oidn``,
    :class:`arlight.denoise.differential.DenoisedLayers`) also write the raw estimate,
    ``noisy_<layer>.exr``, whose standard errors the ``stderr_<layer>.exr`` are.

    The files are staged next to ``out_dir`` and swapped in as one set
    (:class:`arlight.staged_output.StagedOutput`): the folder holds the whole previous
    output or the whole new one, never a mix. A folder holding other files is refused.

    Raises ValueError, before writing anything, when a layer is not a finite float32 array
    of the scene camera's ``(H, W, 3)`` (``(H, W)`` for the mask; standard errors may be
    +inf but not NaN); the message names the layer and the expected shape.
    """
    from arlight.staged_output import StagedOutput

    layers.check(scene.camera.height, scene.camera.width, where="write_layers")
    out = Path(out_dir)
    with StagedOutput(out, "render", LAYER_FILES) as tmp:
        staged = _write_all(layers, scene, tmp)
    return {k: out / p.name for k, p in staged.items()}


def _write_all(layers: Layers, scene: ARScene, out: Path) -> dict[str, Path]:
    paths: dict[str, Path] = {}
    images = {"composite": layers.composite, "mixed": layers.mixed, "delta": layers.delta,
              "mask": layers.mask, "background": layers.background}
    if layers.real is not None:
        images["real"] = layers.real
    for name, img in images.items():
        paths[name] = write_exr(out / f"{name}.exr", img)
    for name, img in layers.stderr.items():
        paths[f"stderr_{name}"] = write_exr(out / f"stderr_{name}.exr", img)
    noisy = getattr(layers, "noisy", None)  # denoised: the raw estimate and its errors too
    if noisy is not None:
        raw = {"composite": noisy.composite, "mixed": noisy.mixed, "delta": noisy.delta}
        if noisy.real is not None:
            raw["real"] = noisy.real
        for name, img in raw.items():
            paths[f"noisy_{name}"] = write_exr(out / f"noisy_{name}.exr", img)
        for name, img in noisy.stderr.items():
            paths[f"stderr_{name}"] = write_exr(out / f"stderr_{name}.exr", img)
    png = scene.camera.transfer.to_display(layers.composite, display_dtype(scene))
    paths["composite_png"] = write_png(out / "composite.png", png)
    with atomic_write(out / "stats.json", ".json") as tmp:
        tmp.write_text(json.dumps({"method": layers.method, **layers.stats}, indent=2))
    paths["stats"] = out / "stats.json"
    return paths
