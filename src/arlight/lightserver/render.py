"""The rendering client: its own camera path and background, the server's light.

:func:`run_client` subscribes with a :class:`~arlight.lightserver.client.LightClient`, waits
for the first state (a snapshot: at once when the server is up), then renders ``frames``
frames with the ``nearfield`` method: each frame reads :attr:`LightClient.latest` **once**
and renders with that complete state (an update arriving mid-frame is used by the next
frame). The camera orbits the scene's vertical axis; the background is the scene's frame.
A lost server does not stop the loop: the last state keeps lighting the frames while the
client reconnects. The frames (``frame_NNNN.png``) and ``client.json`` (per-frame sequence
and epoch, update latencies, counters) are written as one set (:mod:`arlight.staged_output`).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from arlight.errors import InputError
from arlight.lightserver.client import LightClient

CLIENT_FILES = ("frame_*.png", "client.json")


def orbit_pose(world_from_camera: np.ndarray, angle: float) -> np.ndarray:
    """The pose turned by ``angle`` radians about the world's +Y axis through the origin."""
    c, s = math.cos(angle), math.sin(angle)
    rot = np.eye(4)
    rot[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return rot @ np.asarray(world_from_camera, dtype=np.float64)


def camera_path(camera, frames: int, orbit_deg: float) -> list:
    """``frames`` cameras orbiting by ``orbit_deg`` degrees in total."""
    step = math.radians(orbit_deg) / max(frames - 1, 1)
    return [replace(camera, world_from_camera=orbit_pose(camera.world_from_camera, i * step))
            for i in range(frames)]


def _percentile(values, q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if len(values) else float("nan")


def run_client(scene_path: Path, out: Path, *, connect: str, snapshot: str | None,
               frames: int, orbit_deg: float, spp: int, wait: float,
               heartbeat_timeout: float, size: tuple[int, int] | None = None,
               server_public_key: bytes | None = None, client_key=None,
               insecure: bool = False, force: bool = False) -> dict:
    """Render ``frames`` frames of ``scene_path`` lit by the server's latest state; returns
    the summary also written to ``client.json`` (module docstring).

    The render's memory and time (:func:`arlight.bounds.estimate` at the client's size and
    ``spp``, one frame) are checked before anything starts; beyond the limits it is refused
    (InputError naming ``--size``) unless ``force``. ``server_public_key`` / ``client_key``
    / ``insecure``: see :class:`LightClient`.
    """
    from arlight.bounds import check_estimate, estimate
    from arlight.io.images import write_png
    from arlight.lightserver.nearfield_render import NearFieldRenderer
    from arlight.scene.load import load_scene
    from arlight.staged_output import StagedOutput, check_output_dir

    client = LightClient(connect, snapshot, heartbeat_timeout=heartbeat_timeout,
                         server_public_key=server_public_key, client_key=client_key,
                         insecure=insecure)
    scene = load_scene(scene_path)
    if size is not None:
        try:
            scene = scene.resized(*size)
        except ValueError as exc:
            raise InputError(str(exc), file=str(scene_path), field="--size") from exc
    est = estimate(scene.camera.width, scene.camera.height, spp, layers=1)  # per frame
    try:
        check_estimate(est, f"arlight client at {scene.camera.width}x{scene.camera.height}",
                       force)
    except InputError as exc:
        raise InputError(exc.message, field="--size") from exc
    if not scene.has_virtual:
        raise InputError("the client scene has no virtual object to light", file=str(scene_path),
                         field="shapes")
    check_output_dir(out, CLIENT_FILES, 0, (scene_path,))
    per_frame = []
    client.start()
    try:
        light = client.wait_for(1, timeout=wait)  # WireVersionError / no server → exit 2
        renderer = NearFieldRenderer(scene, spp=spp)
        renderer.check(light, str(scene_path))
        with StagedOutput(out, "client", CLIENT_FILES) as tmp:
            for i, cam in enumerate(camera_path(scene.camera, frames, orbit_deg)):
                newest = client.latest  # one read per frame: a whole, validated state
                if newest is not None and newest.n_objects == renderer.n_objects:
                    light = newest
                layers = renderer.render(cam, light)
                write_png(tmp / f"frame_{i:04d}.png", cam.transfer.to_display(layers.composite))
                per_frame.append({"frame": i, "sequence": light.sequence,
                                  "epoch": client.epoch, "vals": light.count})
            st = client.stats()
            lat_ms = [1e3 * v for v in st.latencies]
            summary = {
                "frames": frames, "connect": client.connect, "snapshot": client.snapshot,
                "first_sequence": per_frame[0]["sequence"],
                "last_sequence": per_frame[-1]["sequence"],
                "updates_applied": st.applied, "from_snapshot": st.from_snapshot,
                "gaps": st.gaps, "stale": st.stale, "restarts": st.restarts,
                "reconnects": st.reconnects, "rejected": dict(st.rejected),
                "latency_ms_p50": _percentile(lat_ms, 50),
                "latency_ms_p99": _percentile(lat_ms, 99),
                "latency_ms_max": max(lat_ms) if lat_ms else float("nan"),
                "per_frame": per_frame,
            }
            (tmp / "client.json").write_text(json.dumps(summary, indent=1))
    finally:
        client.close()
    return summary
