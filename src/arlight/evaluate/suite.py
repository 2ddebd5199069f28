"""The evaluation scene suite: AR scenes standing for the papers' test figures.

Each scene is a folder ``arlight/data/scenes/<name>/`` with

* ``world.toml`` — the "real world" used to synthesise the camera frame and the ground truth
  (real shapes = the world, virtual shapes = the insertions); its header comment names the
  paper figure it stands for and what it exercises;
* ``proxy.toml`` (optional) — the proxy geometry a method is given, where it differs from the
  world (e.g. a coarser reconstruction). Without it the proxy is the world itself.

    from arlight.evaluate.suite import get_scene, list_scenes
    s = get_scene("bunny-box", quick=True)          # 80×60
    photo = s.photo(spp=64)                          # frame + ground truth (cached)
    layers = get_method("reference")(s.ar_scene(photo), RenderSettings(spp=16))

``quick=True`` scales the camera to a CI size (80 px wide, same aspect and field of view);
``quick=False`` keeps the papers' resolution written in the file (640×480, or 960×540 for
``cornell-near-field``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from arlight.errors import InputError
from arlight.scene.load import load_scene
from arlight.scene.model import ARScene
from arlight.synthetic import DEFAULT_BATCHES, SyntheticPhoto, synthesize

QUICK_WIDTH = 80  # px; the height keeps the aspect ratio (80×60 for 4:3, 80×45 for 16:9)


def scenes_dir() -> Path:
    """The folder holding the suite's scene folders (inside the installed package)."""
    return Path(str(resources.files("arlight") / "data" / "scenes"))


@dataclass
class SuiteScene:
    """One scene of the suite.

    Attributes:
        name: folder name, e.g. ``"bunny-box"``.
        description: one line (the file's ``description``).
        paper_figure: the paper figure(s) it stands for (first line of the header comment).
        world: the world scene (frame and ground truth are rendered from it).
        proxy: what a method gets: the proxy scene, without a frame until :meth:`ar_scene`.
        quick: whether the camera was scaled down to the CI size.
    """

    name: str
    description: str
    paper_figure: str
    world: ARScene
    proxy: ARScene
    quick: bool = True

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.world.resolution

    def photo(self, spp: int = 256, seed: int = 1, max_depth: int = 8,
              cache_dir: Path | str | None = None, use_cache: bool = True,
              progress: bool = False, batches: int = DEFAULT_BATCHES) -> SyntheticPhoto:
        """The synthetic frame and ground truth of the world (see
        :func:`arlight.synthetic.synthesize`; cached on disk by content hash)."""
        return synthesize(self.world, spp=spp, seed=seed, max_depth=max_depth,
                          cache_dir=cache_dir, use_cache=use_cache, progress=progress,
                          batches=batches)

    def ar_scene(self, photo: SyntheticPhoto) -> ARScene:
        """The proxy with the synthetic frame attached: the input of a method."""
        return self.proxy.with_frame(photo.frame)


def list_scenes() -> list[str]:
    """Names of the suite's scenes (folders with a ``world.toml``), sorted."""
    root = scenes_dir()
    return sorted(p.name for p in root.iterdir() if (p / "world.toml").is_file())


def _read(path: Path, quick: bool) -> tuple[ARScene, dict]:
    scene = load_scene(path)
    if quick:
        w, h = scene.resolution
        scene = scene.resized(QUICK_WIDTH, max(1, round(QUICK_WIDTH * h / w)))
    return scene, scene.raw


def _paper_figure(path: Path) -> str:
    """First header comment line after the ``# name —`` prefix."""
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            text = line.lstrip("# ").strip()
            return re.sub(r"^[\w-]+ — ", "", text)
        break
    return ""


def get_scene(name: str, quick: bool = True) -> SuiteScene:
    """Load a suite scene; unknown names raise :class:`InputError` listing the known ones."""
    names = list_scenes()
    if name not in names:
        raise InputError(f"unknown scene {name!r}; available: {', '.join(names)}",
                         field="scene")
    folder = scenes_dir() / name
    world, data = _read(folder / "world.toml", quick)
    proxy_path = folder / "proxy.toml"
    proxy = _read(proxy_path, quick)[0] if proxy_path.is_file() else world
    if proxy.resolution != world.resolution:
        raise InputError(f"proxy resolution {proxy.resolution} != world {world.resolution}",
                         file=str(proxy_path), field="camera.resolution")
    return SuiteScene(name=name, description=str(data.get("description", "")),
                      paper_figure=_paper_figure(folder / "world.toml"), world=world,
                      proxy=proxy, quick=quick)
