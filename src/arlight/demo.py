"""The bundled demo: a virtual Stanford bunny on a real table, lit by a room and a lamp."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

DEMO_DIR = Path(__file__).parent / "data" / "demo"


def demo_scene_path() -> Path:
    """The demo AR scene file (proxy + camera frame)."""
    return DEMO_DIR / "scene.toml"


def demo_world_path() -> Path:
    """The demo world (the proxy with the bunny) that the frame was synthesised from."""
    return DEMO_DIR / "world.toml"


def run_demo(out: Path, spp: int = 36, method: str = "reference",
             console: Console | None = None) -> dict[str, Path]:
    """Render the demo scene with ``method`` and write its layers to ``out``.

    Returns the written paths (``composite_png`` is the picture to look at).
    """
    from arlight.layer_files import write_layers
    from arlight.methods import RenderSettings, get_method
    from arlight.scene.load import load_scene
    from arlight.timing import format_stages

    console = console or Console(stderr=True)
    scene = load_scene(demo_scene_path())
    console.print(f"rendering the demo scene ({scene.camera.width}×{scene.camera.height}, "
                  f"{spp} spp, method [bold]{method}[/])…")
    layers = get_method(method)(scene, RenderSettings(spp=spp, progress=True))
    paths = write_layers(layers, scene, out)
    console.print(f"done in {layers.stats.get('seconds', 0):.1f} s "
                  f"({layers.stats.get('samples_per_second', 0) / 1e6:.2f} Msamples/s)")
    if stages := format_stages(layers.stats):
        console.print(f"stages: {stages}")
    console.print(f"composite: [bold]{paths['composite_png']}[/]")
    exrs = ", ".join(str(paths[k]) for k in ("mixed", "delta", "mask", "real") if k in paths)
    console.print(f"layers (EXR, linear radiance): {exrs}")
    return paths
