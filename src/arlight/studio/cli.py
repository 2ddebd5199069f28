"""``arlight studio SCENE``: serve the live AR composite of a scene in the browser."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _resolution(text: str | None) -> tuple[int, int] | None:
    from arlight.errors import InputError

    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or min(size) < 1 or max(size) > 8192:
        raise InputError(f"expected WIDTHxHEIGHT (e.g. 320x240), got {text!r}",
                         field="--resolution")
    return size


def _check_host(host: str) -> None:
    """An address this machine can bind: an IP literal or a name that resolves."""
    import ipaddress
    import socket

    from arlight.errors import InputError

    try:
        ipaddress.ip_address(host.strip("[]"))
        return
    except ValueError:
        pass
    try:
        socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise InputError(f"{host!r} is not an address or a name that resolves ({exc})",
                         field="--host") from exc


def _check_save_dir(save_dir: Path | None) -> None:
    """The save folder must be an existing, writable folder (never a file or a dangling
    link): a save must not be the first to find out."""
    import os

    from arlight.errors import InputError

    if save_dir is None:
        return
    where = str(save_dir)
    if os.path.islink(save_dir) and not save_dir.exists():
        raise InputError(f"is a dangling symlink (to {os.readlink(save_dir)})", file=where,
                         field="--save-dir")
    if not save_dir.exists():
        raise InputError("does not exist (create the folder first)", file=where,
                         field="--save-dir")
    if not save_dir.is_dir():
        raise InputError("is not a folder", file=where, field="--save-dir")
    if not os.access(save_dir, os.W_OK | os.X_OK):
        raise InputError("is not writable", file=where, field="--save-dir")


def _check_method(method: str | None) -> None:
    from arlight.errors import InputError
    from arlight.methods import available_methods

    if method is not None and method not in available_methods():
        raise InputError(f"unknown method {method!r}; available: "
                         f"{', '.join(available_methods())}", field="--method")


def studio_command(
    scene: Annotated[Path, typer.Argument(help="AR scene file with a frame and at least one "
                                          "virtual shape")],
    port: Annotated[int, typer.Option("--port", help="TCP port (0: any free port)",
                                      min=0, max=65535)] = 8000,
    host: Annotated[str, typer.Option("--host", help="address to bind; the default serves "
                                      "this machine only")] = "127.0.0.1",
    resolution: Annotated[str | None, typer.Option("--resolution", help="studio frame size "
                          "WIDTHxHEIGHT, an integer fraction of the scene's (e.g. 320x240); "
                          "default: the scene's")] = None,
    method: Annotated[str | None, typer.Option("--method", "-m", help="first method (an "
                      "interactive one; default: the scene's render table, else dir)")] = None,
    save_dir: Annotated[Path | None, typer.Option("--save-dir", help="folder the save "
                        "button writes to (default: the scene's folder)")] = None,
    ground_truth: Annotated[Path | None, typer.Option("--ground-truth", help="ground-truth "
                            "EXR for the error layer (default: ground_truth.exr beside the "
                            "scene, if any)")] = None,
    image_format: Annotated[str, typer.Option("--format", help="frame encoding: jpeg, png "
                                              "or webp")] = "jpeg",
    quality: Annotated[int, typer.Option("--quality", help="JPEG/WebP quality",
                                         min=1, max=100)] = 85,
    token: Annotated[str | None, typer.Option("--token", envvar="ARLIGHT_STUDIO_TOKEN",
                     show_envvar=True, help="the token the page and WebSocket must give "
                     "(16+ URL-safe characters; default: a random one per launch, printed "
                     "in the URL)")] = None,
    max_sessions: Annotated[int, typer.Option("--max-sessions", help="most tabs open at "
                            "once; a further one is refused (HTTP 503)", min=1,
                            max=4096)] = 16,
    frame_budget_ms: Annotated[float, typer.Option("--frame-budget-ms", help="render budget "
                               "of a frame while the pointer drags, milliseconds: frames are "
                               "rendered at 1/2, 1/4 or 1/8 of the size to keep it and "
                               "upsampled (0: always full size)", min=0.0,
                               max=60000.0)] = 100.0,
    rest_ms: Annotated[float, typer.Option("--rest-ms", help="the pointer rests after this "
                       "many milliseconds without a drag; the frame is then rendered at full "
                       "size once", min=0.0, max=60000.0)] = 150.0,
    drag_threads: Annotated[int, typer.Option("--drag-threads", help="Dr.Jit worker threads "
                            "while a drag frame renders (0: one per core, as full-size "
                            "frames)", min=0, max=256)] = 1,
    drag_calls: Annotated[str, typer.Option("--drag-calls", help="Dr.Jit virtual calls "
                          "of drag frames: evaluated (only the shapes/BSDFs reached) or "
                          "symbolic (every one alive traced)")] = "evaluated",
) -> None:
    """Live AR composite in the browser: drag the virtual object, switch methods.

    Serves http://HOST:PORT/?token=... (the URL it prints; a new token each launch):
    drag the object on the real surface (its shadow and bounce
    light follow), rotate and scale it, switch between the interactive methods (progressive
    ones refine while idle), change the exposure and the layer, save the scene. See
    docs/studio.md.
    """
    from rich.console import Console

    from arlight.studio.access import is_loopback
    from arlight.studio.engine import Engine, StudioConfig
    from arlight.studio.server import resolve_token, serve

    token = resolve_token(token)  # a bad option fails before the scene loads
    _check_host(host)
    _check_save_dir(save_dir)
    _check_method(method)
    config = StudioConfig(scene=scene, resolution=_resolution(resolution), method=method,
                          save_dir=save_dir, ground_truth=ground_truth,
                          image_format=image_format.lower(), quality=quality,
                          max_sessions=max_sessions, frame_budget_ms=frame_budget_ms,
                          rest_ms=rest_ms, drag_threads=drag_threads,
                          drag_calls=drag_calls.lower())
    engine = Engine(config)
    console = Console(stderr=True)
    if not is_loopback(host):
        console.print(f"[yellow]warning:[/] binding {host}: anyone on the network who "
                      "gets the URL with its token can use the studio and write files "
                      "into its save folder, and the traffic (token included) is plain "
                      "HTTP; prefer the default 127.0.0.1 and an SSH tunnel", soft_wrap=True)
    console.print("preparing the scene…")
    # soft_wrap: the URL with its token stays on one line, whole, at any terminal width
    serve(engine, host, port, token=token,
          print_fn=lambda text: console.print(text, soft_wrap=True, highlight=False))
