"""The server's real producer: Rohmer's pipeline on a stream of fisheye HDR frames.

:class:`PipelineProducer` feeds frame ``i`` of a frame source to
:class:`arlight.nearfield.pipeline.NearFieldServer` (radiance atlas → τ split → VALs by
warm-started k-means → SH per virtual object; issue 17) and returns its
:class:`~arlight.nearfield.NearFieldLight`. The rig and the proxy do not change while the
server runs, so the camera→texel weights and visibility are computed by the first update
only (the server's projection cache, issue #32); every later update re-projects radiance.
Frame sources:

- :class:`FolderFrames`: a folder with one sub-folder per frame (natural name order), each
  holding one HDR image per rig camera named ``<camera name>.exr`` (or ``.hdr``/``.pfm``);
  the stream loops over the frames.
- :class:`MovingLightFrames`: frames synthesised on the fly by Mitsuba's path tracer
  (:func:`arlight.nearfield.capture.capture_rig`) in the world whose first area light moves
  on a circle in its own plane, ``loop`` positions per revolution; each position is rendered
  once and cached, so a long-running server cycles through them.

:func:`write_frames` stores a source's frames in the folder layout (test data, recordings).
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from arlight.errors import InputError
from arlight.nearfield.cameras import default_rig  # re-exported: tests, benchmarks
from arlight.nearfield.state import NearFieldLight
from arlight.scene.model import Light, World

IMAGE_SUFFIXES = (".exr", ".hdr", ".pfm")


def _natural(name: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


class FolderFrames:
    """Frames from ``folder/<frame>/<camera>.exr`` (module docstring); checked up front."""

    def __init__(self, folder: str | Path, camera_names: list[str]):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise InputError("not a folder of frames", file=str(self.folder), field="--frames")
        self.frames = sorted((d for d in self.folder.iterdir() if d.is_dir()),
                             key=lambda d: _natural(d.name))
        if not self.frames:
            raise InputError("no frame sub-folders (expected <frame>/<camera>.exr)",
                             file=str(self.folder), field="--frames")
        self.paths = []
        for d in self.frames:
            row = []
            for cam in camera_names:
                found = [d / f"{cam}{s}" for s in IMAGE_SUFFIXES if (d / f"{cam}{s}").exists()]
                if not found:
                    raise InputError(f"no image for camera {cam!r} (expected {cam}.exr)",
                                     file=str(d), field="--frames")
                row.append(found[0])
            self.paths.append(row)

    def __len__(self) -> int:
        return len(self.frames)

    def __call__(self, frame: int) -> list[np.ndarray]:
        from arlight.io.images import read_linear

        return [read_linear(p) for p in self.paths[frame % len(self.paths)]]


def moved_light(light: Light, offset: np.ndarray) -> Light:
    """The light translated by ``offset`` (m) in the world."""
    p = dict(light.params)
    m = np.array(p["to_world"], dtype=np.float64)
    m[:3, 3] += offset
    p["to_world"] = m
    return replace(light, params=p)


class MovingLightFrames:
    """Fisheye frames of ``world`` with its first area light on a circle (module docstring).

    Args:
        world: the real world the cameras see (its real shapes and lights).
        rig: the fisheye cameras.
        radius: radius of the light's circle in its own plane, m.
        loop: light positions per revolution (frames before the stream repeats).
        spp: path samples per pixel of the synthetic capture.
        seed: capture seed.
    """

    def __init__(self, world: World, rig, radius: float = 0.4, loop: int = 24, spp: int = 8,
                 seed: int = 0):
        self.world, self.rig = world, list(rig)
        self.index = next((i for i, li in enumerate(world.lights) if li.type == "area"), None)
        if self.index is None:
            raise InputError("the world has no area light to move", file=str(world.source),
                             field="lights")
        if loop < 1 or radius < 0 or spp < 1:
            raise InputError("loop >= 1, radius >= 0 and spp >= 1 required", field="frames")
        m = np.asarray(world.lights[self.index].params["to_world"], dtype=np.float64)
        self.u = m[:3, 0] / np.linalg.norm(m[:3, 0])
        self.v = m[:3, 1] / np.linalg.norm(m[:3, 1])
        self.radius, self.loop, self.spp, self.seed = float(radius), int(loop), int(spp), seed
        self._cache: dict[int, list[np.ndarray]] = {}

    def world_at(self, frame: int) -> World:
        """The world with the light at its position for ``frame``."""
        a = 2.0 * math.pi * (frame % self.loop) / self.loop
        off = self.radius * (math.cos(a) * self.u + math.sin(a) * self.v)
        lights = list(self.world.lights)
        lights[self.index] = moved_light(lights[self.index], off)
        return replace(self.world, lights=lights)

    def __len__(self) -> int:
        return self.loop

    def __call__(self, frame: int) -> list[np.ndarray]:
        from arlight.nearfield.capture import capture_rig

        k = frame % self.loop
        if k not in self._cache:
            self._cache[k] = capture_rig(self.world_at(k), self.rig, self.spp, self.seed + k)
        return self._cache[k]


class PipelineProducer:
    """frame index → NearFieldLight by Rohmer's pipeline on ``frames(i)``."""

    def __init__(self, server, frames):
        self.server = server
        self.frames = frames

    def __call__(self, frame: int) -> NearFieldLight:
        return self.server.update(self.frames(frame))


def pipeline_producer(world_path: Path | None, frames: Path | None, *, vals: int = 16,
                      rig_path: Path | None = None, camera_size: int = 64,
                      atlas: int = 128, tau: float = 0.9, spp: int = 8,
                      loop: int = 24) -> PipelineProducer:
    """The producer of ``arlight serve-light --source pipeline`` (module docstring)."""
    from arlight.nearfield.cameras import load_rig
    from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings
    from arlight.scene.load import load_scene

    if world_path is None:
        raise InputError("--source pipeline needs --world SCENE (the proxy and the virtual "
                         "objects)", field="--world")
    world = load_scene(world_path).world
    rig = load_rig(rig_path) if rig_path is not None else default_rig(world, camera_size)
    source = (FolderFrames(frames, [c.name for c in rig]) if frames is not None
              else MovingLightFrames(world, rig, loop=loop, spp=spp))
    server = NearFieldServer(world, rig, NearFieldSettings(atlas_resolution=atlas, vals=vals,
                                                           tau=tau))
    return PipelineProducer(server, source)


def write_frames(source, rig, folder: str | Path, count: int) -> Path:
    """Write ``count`` frames of ``source`` as ``folder/NNNN/<camera>.exr``."""
    from arlight.io.images import write_exr

    folder = Path(folder)
    for i in range(count):
        d = folder / f"{i:04d}"
        d.mkdir(parents=True, exist_ok=True)
        for cam, img in zip(rig, source(i), strict=True):
            write_exr(d / f"{cam.name}.exr", img)
    return folder
