"""``arlight serve-light`` and ``arlight client`` (see docs/lightserver.md)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Annotated

import typer

from arlight.errors import InputError

DEFAULT_BIND = "tcp://127.0.0.1:5556"
MAX_DURATION = 10 * 365 * 86400.0
"""Largest --duration, s (ten years; 0 = until interrupted)."""
MAX_ORBIT = 36000.0
"""Largest |--orbit|, degrees (a hundred turns)."""


def _finite(**options: tuple[float, float, float]) -> None:
    """Each option ``name=(value, lo, hi)`` finite and within [lo, hi] (typer's ranges let
    NaN through); InputError naming ``--name``."""
    from arlight.bounds import check_range

    for name, (value, lo, hi) in options.items():
        check_range(value, "--" + name.replace("_", "-"), lo, hi)


def _estimate_check(est, what: str, field: str, force: bool) -> None:
    """bounds.check_estimate, naming ``field`` instead of the generic "bounds"."""
    from arlight.bounds import check_estimate

    try:
        check_estimate(est, what, force)
    except InputError as exc:
        raise InputError(exc.message, field=field) from exc


def _pipeline_estimate(camera_size: int, spp: int, loop: int, atlas: int, cameras: int = 6):
    """Memory and time of --source pipeline with synthesised frames: one capture render of
    ``camera_size``² px (or the atlas projection, whichever is larger) plus the cache of
    every rendered frame (``loop`` × ``cameras`` float RGB images); time: every capture."""
    from arlight.bounds import Estimate, estimate

    render = estimate(camera_size, camera_size, spp, renders=cameras * loop)
    projection = estimate(atlas, atlas, 1)
    cache = float(loop) * cameras * camera_size * camera_size * 3 * 4
    return Estimate(max(render.memory_bytes, projection.memory_bytes) + cache,
                    render.seconds, 0.0)

def _objects(text: str | None) -> list[list[float]]:
    """``"x,y,z;x,y,z"`` → object centres (m)."""
    if not text:
        return [[0.0, 0.1, 0.0]]
    out = []
    for part in text.split(";"):
        try:
            xyz = [float(v) for v in part.split(",")]
        except ValueError:
            xyz = []
        if len(xyz) != 3:
            raise InputError(f"{part!r}: expected X,Y,Z in metres (objects separated by ';')",
                             field="--objects")
        if not all(math.isfinite(v) and abs(v) <= 1e4 for v in xyz):
            raise InputError(f"{part!r}: coordinates must be finite, |x| <= 10000 m",
                             field="--objects")
        out.append(xyz)
    if len(out) > 4096:
        raise InputError(f"{len(out)} objects; the wire carries at most 4096",
                         field="--objects")
    return out


def _size(text: str | None) -> tuple[int, int] | None:
    """``"WxH"`` → (W, H) in pixels."""
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        w = h = 0
    if not (1 <= w <= 8192 and 1 <= h <= 8192):
        raise InputError(f"{text!r}: expected WxH, 1..8192 pixels each", field="--size")
    return w, h


def serve_light_command(
    source: Annotated[str, typer.Option("--source", help="where the light comes from: "
                      "`pipeline` (Rohmer's radiance atlas → τ split → VALs → SH on fisheye "
                      "HDR frames: --world, and --frames or frames synthesised on the fly) or "
                      "`synthetic` (an analytic moving lamp, no cameras; see "
                      "docs/lightserver.md)")] = "synthetic",
    world: Annotated[Path | None, typer.Option("--world", help="scene file of the world "
                     "(real proxy, virtual objects; its lights light the synthesised frames) "
                     "for --source pipeline")] = None,
    frames: Annotated[Path | None, typer.Option("--frames", help="folder of fisheye HDR "
                      "frames for --source pipeline (see docs/lightserver.md); default: "
                      "frames synthesised on the fly with a moving light")] = None,
    bind: Annotated[str, typer.Option("--bind", help="ZeroMQ publish endpoint "
                    "(tcp://HOST:PORT; PORT * = any free port)")] = DEFAULT_BIND,
    snapshot_bind: Annotated[str | None, typer.Option("--snapshot-bind", help="snapshot "
                             "endpoint for late joiners (default: --bind's port + 1)")] = None,
    rate: Annotated[float, typer.Option("--rate", help="updates per second at most (0 = as "
                    "fast as the pipeline)", min=0, max=1000)] = 18.0,
    count: Annotated[int, typer.Option("--count", help="stop after this many updates "
                     "(0 = run until interrupted)", min=0)] = 0,
    duration: Annotated[float, typer.Option("--duration", help="stop after this many "
                        "seconds (0 = run until interrupted)", min=0)] = 0.0,
    heartbeat: Annotated[float, typer.Option("--heartbeat", help="heartbeat period when "
                         "idle, seconds", min=0.01, max=60)] = 0.25,
    vals: Annotated[int, typer.Option("--vals", help="number of VALs M (Rohmer: 8..64; at "
                                      "most what the nearfield method renders, 256)",
                                      min=1)] = 16,
    objects: Annotated[str | None, typer.Option("--objects", help="--source synthetic: "
                       "virtual object centres X,Y,Z;X,Y,Z (m), one SH block each")] = None,
    rig: Annotated[Path | None, typer.Option("--rig", help="--source pipeline: fisheye rig "
                   "(cams.toml); default: six 180° cameras inside the real geometry")] = None,
    camera_size: Annotated[int, typer.Option("--camera-size", help="pixels per side of the "
                           "default rig's cameras", min=8, max=4096)] = 64,
    atlas: Annotated[int, typer.Option("--atlas", help="radiance atlas side, texels "
                     "(Rohmer: 1024)", min=16, max=4096)] = 128,
    tau: Annotated[float, typer.Option("--tau", help="direct share of the total light "
                   "(Rohmer: 0.75-0.98)", min=0.0, max=1.0)] = 0.9,
    spp: Annotated[int, typer.Option("--spp", help="samples per pixel of frames "
                   "synthesised on the fly", min=1, max=4096)] = 8,
    loop: Annotated[int, typer.Option("--loop", help="light positions per revolution of "
                    "the moving light (synthesised frames; the stream repeats after)",
                    min=1, max=10_000)] = 24,
    keygen: Annotated[Path | None, typer.Option("--keygen", help="write CURVE key pairs "
                      "into this folder (server.key / server.key_secret, client.key / "
                      "client.key_secret; secrets mode 0600; never overwrites) and exit")
                      ] = None,
    server_key: Annotated[Path | None, typer.Option("--server-key", help="the server's "
                          "secret key file (.key_secret): CURVE authentication and "
                          "encryption on both sockets; needed off loopback")] = None,
    allow_clients: Annotated[Path | None, typer.Option("--allow-clients", help="folder of "
                             "client public keys (*.key): only these clients get through "
                             "(with --server-key; default: any client that knows the "
                             "server's public key)")] = None,
    insecure: Annotated[bool, typer.Option("--insecure", help="serve off loopback without "
                        "keys: no authentication, no encryption (a warning is printed)")
                        ] = False,
    max_clients: Annotated[int, typer.Option("--max-clients", help="connections each socket "
                           "admits at once", min=1, max=65536)] = 256,
    force: Annotated[bool, typer.Option("--force", help="run even when the memory or time "
                     "estimate of the synthesised frames exceeds the limits")] = False,
) -> None:
    """Run the near-field light server: publish each light update (VALs + SH per object)
    to every subscribed client, in Rohmer's binary layout (32 B per VAL, 108 B per object).

    Stops after --count updates or --duration seconds, or on Ctrl-C (exit 130). Off
    loopback it needs CURVE keys (--keygen, --server-key); see docs/lightserver.md.
    """
    from arlight.lightserver import security, transport

    _finite(rate=(rate, 0, 1000), duration=(duration, 0, MAX_DURATION),
            heartbeat=(heartbeat, 0.01, 60), tau=(tau, 0, 1))
    if keygen is not None:
        for p in security.keygen(keygen):
            typer.echo(f"wrote {p}", err=True)
        typer.echo("give server.key_secret to --server-key, server.key to every client "
                   "(--server-public-key), client.key_secret to a client (--client-key) and "
                   "put allowed client .key files in the --allow-clients folder", err=True)
        return
    transport.check_endpoint(bind, "--bind", bind=True)
    snap_addr = snapshot_bind or transport.next_port_endpoint(bind)
    transport.check_endpoint(snap_addr, "--snapshot-bind", bind=True)
    curve = security.load_secret(server_key, "--server-key") if server_key else None
    if allow_clients is not None and curve is None:
        raise InputError("needs --server-key (client keys are checked by CURVE)",
                         field="--allow-clients")
    allowed = security.load_allowed(allow_clients) if allow_clients is not None else None
    warnings = security.check_exposure({"--bind": bind, "--snapshot-bind": snap_addr},
                                       curve is not None, insecure)
    if source == "pipeline" and frames is None and rig is None:
        _estimate_check(_pipeline_estimate(camera_size, spp, loop, atlas),
                        f"--source pipeline with {camera_size} px cameras", "--camera-size",
                        force)
    from arlight.lightserver import wire
    from arlight.lightserver.producers import SyntheticMovingLight
    from arlight.lightserver.server import LightServer

    if vals > wire.MAX_VALS:
        raise InputError(f"{vals} VALs; clients render at most {wire.MAX_VALS} (the "
                         "nearfield method's limit, enforced on the wire)", field="--vals")
    if source == "synthetic":
        if world is not None or frames is not None:
            raise InputError("--world/--frames need --source pipeline", field="--source")
        producer = SyntheticMovingLight(vals=vals, objects=_objects(objects),
                                        frame_dt=1.0 / rate if rate > 0 else 1.0 / 18.0)
    elif source == "pipeline":
        from arlight.lightserver.pipeline import pipeline_producer

        producer = pipeline_producer(world, frames, vals=vals, rig_path=rig,
                                     camera_size=camera_size, atlas=atlas, tau=tau, spp=spp,
                                     loop=loop)
    else:
        raise InputError(f"{source!r}: expected pipeline or synthetic", field="--source")
    server = LightServer(producer, bind=bind, snapshot_bind=snapshot_bind, rate_hz=rate,
                         heartbeat_s=heartbeat, count=count or None,
                         duration=duration or None, curve=curve, allow_clients=allowed,
                         insecure=insecure, max_clients=max_clients)
    for line in warnings:
        typer.echo(f"warning: {line}", err=True)
    pub, snap = server.endpoints
    auth = ("CURVE, " + ("allowed client keys only" if allowed else "any client key")
            if curve else "no authentication")
    typer.echo(f"serving near-field light ({source}) on {pub}, snapshots on {snap}; "
               f"epoch {server.epoch:08x}; {auth}", err=True)
    try:
        server.run()
    finally:
        s = server.stats()
        ms = sorted(s.produce_seconds)
        med = f"{1e3 * ms[len(ms) // 2]:.1f} ms" if ms else "n/a"
        typer.echo(f"published {s.published} updates ({s.bytes_last} B each), "
                   f"{s.heartbeats} heartbeats, {s.snapshots} snapshots; producer median "
                   f"{med}", err=True)


def client_command(
    scene: Annotated[Path, typer.Argument(help="AR scene file: the client's world (real "
                                          "proxy, virtual objects), camera and background "
                                          "frame")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder: frame_NNNN.png "
                                      "and client.json")],
    connect: Annotated[str, typer.Option("--connect", help="the server's publish "
                       "endpoint")] = DEFAULT_BIND,
    snapshot: Annotated[str | None, typer.Option("--snapshot", help="the server's snapshot "
                        "endpoint (default: --connect's port + 1)")] = None,
    frames: Annotated[int, typer.Option("--frames", help="frames to render", min=1,
                                        max=100_000)] = 30,
    orbit: Annotated[float, typer.Option("--orbit", help="camera path: degrees the camera "
                     "turns about the vertical axis through the scene origin over all "
                     "frames")] = 30.0,
    spp: Annotated[int, typer.Option("--spp", help="samples per pixel of the nearfield "
                                     "render", min=1, max=4096)] = 1,
    size: Annotated[str | None, typer.Option("--size", help="render size WxH (default: the "
                    "scene camera's; the field of view is kept)")] = None,
    wait: Annotated[float, typer.Option("--wait", help="seconds to wait for the first "
                    "light state (exit 2 without one)", min=0.1, max=3600)] = 30.0,
    heartbeat_timeout: Annotated[float, typer.Option("--heartbeat-timeout", help="seconds "
                                 "of silence before the server counts as lost and the "
                                 "client reconnects", min=0.05, max=600)] = 1.0,
    server_public_key: Annotated[Path | None, typer.Option("--server-public-key", help="the "
                                 "server's public key file (server.key): CURVE, and only "
                                 "that server is believed; needed off loopback")] = None,
    client_key: Annotated[Path | None, typer.Option("--client-key", help="this client's "
                          "secret key file (.key_secret), for a server that allows only "
                          "known clients (default: a fresh key pair)")] = None,
    insecure: Annotated[bool, typer.Option("--insecure", help="connect off loopback "
                        "without the server's key (no authentication)")] = False,
    force: Annotated[bool, typer.Option("--force", help="render even when the memory or "
                     "time estimate exceeds the limits")] = False,
) -> None:
    """Subscribe to a light server and render this client's own frames with the `nearfield`
    method and the latest light state; writes the frames and update-latency statistics."""
    _finite(orbit=(orbit, -MAX_ORBIT, MAX_ORBIT), wait=(wait, 0.1, 3600),
            heartbeat_timeout=(heartbeat_timeout, 0.05, 600))
    wh = _size(size)
    from arlight.lightserver import security

    server_pub = (security.load_public(server_public_key, "--server-public-key")
                  if server_public_key is not None else None)
    if client_key is not None and server_pub is None:
        raise InputError("needs --server-public-key", field="--client-key")
    pair = security.load_secret(client_key, "--client-key") if client_key else None
    from arlight.lightserver.render import run_client

    t0 = time.time()
    summary = run_client(scene, out, connect=connect, snapshot=snapshot, frames=frames,
                         orbit_deg=orbit, spp=spp, wait=wait,
                         heartbeat_timeout=heartbeat_timeout, size=wh,
                         server_public_key=server_pub, client_key=pair, insecure=insecure,
                         force=force)
    typer.echo(f"{summary['frames']} frames in {time.time() - t0:.1f} s with light updates "
               f"{summary['first_sequence']}..{summary['last_sequence']} "
               f"({summary['updates_applied']} received, latency p50 "
               f"{summary['latency_ms_p50']:.2f} ms, p99 {summary['latency_ms_p99']:.2f} ms); "
               f"written to {out}/", err=True)
