"""Rendering a sequence's frames as Ray tasks (``--ray auto`` / ``--ray ADDRESS``).

Ray is imported here only, when a run asks for it; nothing else in arlight needs it.

* **Connecting** (:func:`connect`): ``auto`` starts a private local Ray instance with
  ``workers × threads`` CPUs and un-niced workers (Ray's default niceness 15 starves the
  rendering on a machine shared with other work); ``HOST:PORT`` (the head node's GCS
  address, as printed by ``ray start --head``) or ``ray://HOST:PORT`` (Ray Client) joins
  an existing cluster. The address is checked with a plain TCP connection first
  (:data:`CONNECT_TIMEOUT_S`), so an unreachable cluster is a clear :class:`InputError`
  before any output exists.
* **Tasks**: one task per frame (per part of a frame with ``split``), ``num_cpus =
  threads`` (the Dr.Jit threads each worker process uses,
  :func:`arlight.sequence.job.configure_threads`), ``max_retries`` =
  :data:`MAX_RETRIES`: when a worker process or node dies mid-task, Ray runs the task again
  elsewhere and nothing is lost. The job (world, poses, settings) is put in Ray's object
  store once; each task carries its frame's pixels. Every worker process imports arlight
  itself (the Mitsuba variant is set there) and prepares the method once per job
  (:func:`arlight.sequence.job.prepared`), then renders every frame it is given from that
  state.
* **Flow**: at most ``2 × workers`` tasks are in flight (frames are decoded as tasks are
  submitted, so a long video is never held in memory); results are handed to ``on_result``
  in completion order (a split frame once all its parts are in, merged by
  :func:`arlight.sequence.job.merge_parts`), which writes them at once.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterable
from typing import Any

from arlight.errors import InputError
from arlight.sequence.frames import InputFrame
from arlight.sequence.job import FrameResult, SequenceJob, merge_parts, render_frame

MAX_RETRIES = 3
"""Times Ray re-runs a frame whose worker process died (system failures only)."""
CONNECT_TIMEOUT_S = 5.0
"""Seconds to wait for the TCP connection to a cluster's address."""


def _check_reachable(address: str) -> None:
    target = address.removeprefix("ray://")
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        raise InputError(f"expected auto, HOST:PORT or ray://HOST:PORT, got {address!r}",
                         field="--ray")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise InputError(f"cannot reach the Ray cluster at {address} ({exc}); start it with "
                         "`ray start --head` (see docs/sequence.md)", field="--ray") from exc


def connect(address: str, workers: int | None, threads: int = 1) -> dict[str, Any]:
    """Start or join Ray; returns ``{"address", "cpus", "nodes", "max_node_cpus"}``.

    ``auto`` starts a local instance with ``workers × threads`` CPUs (``workers`` default:
    all CPUs / ``threads``), so that ``workers`` tasks of ``threads`` CPUs each run at once.
    InputError when Ray is not installed, the cluster cannot be reached, or no node has
    ``threads`` CPUs (the tasks could never be scheduled)."""
    try:
        import ray
    except ImportError as exc:
        raise InputError("Ray is not installed; `pip install \"ray[default]\"` (or run "
                         "without --ray)", field="--ray") from exc
    if ray.is_initialized():
        ray.shutdown()
    kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                          "configure_logging": False}
    try:
        if address == "auto":
            n = workers or max(1, (os.cpu_count() or 1) // threads)
            # Ray nices its workers to 15 by default: on a machine shared with other work
            # the rendering would then get only the CPU time nobody else wants
            ray.init(num_cpus=n * threads, _system_config={"worker_niceness": 0}, **kw)
        else:
            _check_reachable(address)
            ray.init(address=address, **kw)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - Ray raises ConnectionError, RuntimeError, ...
        raise InputError(f"cannot start or join Ray at {address!r} "
                         f"({type(exc).__name__}: {exc})", field="--ray") from exc
    res = ray.cluster_resources()
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    biggest = max((float(n.get("Resources", {}).get("CPU", 0)) for n in nodes), default=0.0)
    if biggest < threads:
        ray.shutdown()
        raise InputError(f"each task asks for {threads} CPUs (--threads) but the largest Ray "
                         f"node has {biggest:g}; lower --threads", field="--threads")
    return {"address": address, "cpus": float(res.get("CPU", 0)), "nodes": len(nodes),
            "max_node_cpus": biggest}


def shutdown() -> None:
    import ray

    if ray.is_initialized():
        ray.shutdown()


def _remote_render(job: SequenceJob, frame: InputFrame, depth, part: int) -> FrameResult:
    return render_frame(job, frame, depth, part)


def run(job: SequenceJob, frames: Iterable[tuple[InputFrame, Any]], workers: int,
        on_result: Callable[[FrameResult], None]) -> None:
    """Render ``frames`` (``(frame, depth)`` pairs) as Ray tasks, ``on_result`` for each
    result as it completes. A task that raises (bad input in a frame, a method error) fails
    the run with that error; a dead worker is retried by Ray."""
    import ray

    threads = job.threads or 1
    task = ray.remote(num_cpus=threads, max_retries=MAX_RETRIES)(_remote_render)
    job_ref = ray.put(job)
    pending: list[Any] = []
    parts: dict[int, list[FrameResult]] = {}
    it = iter(frames)
    exhausted = False
    window = max(2, 2 * workers)
    try:
        while True:
            while not exhausted and len(pending) < window:
                nxt = next(it, None)
                if nxt is None:
                    exhausted = True
                    break
                frame, depth = nxt
                frame_ref = ray.put(frame)  # once, for all the parts of the frame
                pending += [task.remote(job_ref, frame_ref, depth, k)
                            for k in range(job.split)]
            if not pending:
                return
            ready, pending = ray.wait(pending, num_returns=1)
            try:
                res = ray.get(ready[0])
            except ray.exceptions.RayTaskError as exc:
                cause = exc.cause if hasattr(exc, "cause") else exc
                raise cause from None
            got = parts.setdefault(res.index, [])
            got.append(res)
            if len(got) == job.split:
                on_result(merge_parts(job, parts.pop(res.index)))
    finally:
        for ref in pending:  # interrupted or failed: do not leave work running
            ray.cancel(ref, force=True)


__all__ = ["CONNECT_TIMEOUT_S", "MAX_RETRIES", "connect", "run", "shutdown"]
