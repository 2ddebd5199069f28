"""``arlight live``: live AR from a camera or a video, shown in the studio page."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_SEED, MAX_SPP
from arlight.errors import InputError

DATA = Path(__file__).resolve().parent.parent / "data" / "live"
EXAMPLE = {"scene": DATA / "scene.toml", "video": DATA / "marker_orbit.mp4",
           "calib": DATA / "calibration.json",
           "marker": "charuco:5x7:0.04:0.03:DICT_4X4_50"}
"""The bundled example (``--example``): a synthetic moving-camera video of a ChArUco board
(:mod:`arlight.live.marker_video`), its calibration, and a scene with a virtual bunny."""


def live_command(
    scene: Annotated[Path | None, typer.Argument(
        help="AR scene file whose world frame is the marker's (+Y up out of the board, m), "
             "as `arlight insert` writes; its render table gives defaults. Omit with "
             "--example")] = None,
    video: Annotated[Path | None, typer.Option(
        "--video", help="play a video file (or a folder of images) at its own frame rate "
                        "(frames arriving while one renders are dropped, never queued)")] = None,
    camera: Annotated[int | None, typer.Option(
        "--camera", help="OpenCV VideoCapture index of a camera (0: the first)", min=0,
        max=255)] = None,
    calib: Annotated[Path | None, typer.Option(
        "--calib", help="camera calibration (OpenCV YAML/XML or JSON K/dist/size) at the "
                        "frames' resolution")] = None,
    marker: Annotated[str | None, typer.Option(
        "--marker", help="printed target tracked per frame: "
                         "charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT or "
                         "aruco:SIDE_M:DICT[:ID] (sizes in metres)")] = None,
    depth: Annotated[Path | None, typer.Option(
        "--depth", help="folder of depth images, one per video frame (metres along the "
                        "camera's +z; EXR/NPY, or 16-bit PNG with --depth-units): RGB-D "
                        "input for methods that use the sensor's depth (probeless)")] = None,
    depth_units: Annotated[float | None, typer.Option(
        "--depth-units", help="raw depth units per metre of 16-bit PNGs (1000: mm)",
        min=1e-6, max=1e9)] = None,
    example: Annotated[bool, typer.Option(
        "--example", help="the bundled example: its scene, video, calibration and marker "
                          "(each replaceable by its own option)")] = False,
    method: Annotated[str | None, typer.Option(
        "--method", "-m", help="registered interactive method (default: the scene's render "
                               "table, else dir)")] = None,
    light: Annotated[Path | None, typer.Option(
        "--light", help="light estimate JSON (`arlight light estimate`) replacing the "
                        "scene's lights")] = None,
    light_server: Annotated[str | None, typer.Option(
        "--light-server", help="the light server's publish endpoint (e.g. "
                               "tcp://127.0.0.1:5556): its newest state lights each frame "
                               "(method nearfield)")] = None,
    light_snapshot: Annotated[str | None, typer.Option(
        "--light-snapshot", help="the light server's snapshot endpoint (default: "
                                 "--light-server's port + 1)")] = None,
    light_wait: Annotated[float, typer.Option(
        "--light-wait", help="seconds to wait for the light server's first state", min=0.1,
        max=3600)] = 10.0,
    server_public_key: Annotated[Path | None, typer.Option(
        "--server-public-key", help="the light server's public key file (CURVE; needed off "
                                    "loopback)")] = None,
    insecure: Annotated[bool, typer.Option(
        "--insecure", help="subscribe to a light server off loopback without its key (no "
                           "authentication)")] = False,
    spp: Annotated[int | None, typer.Option("--spp", help="samples per pixel", min=1,
                                            max=MAX_SPP)] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="seed of every frame", min=0,
                                             max=MAX_SEED)] = None,
    option: Annotated[list[str] | None, typer.Option(
        "--option", help="method option key=value (repeatable)")] = None,
    fps: Annotated[float | None, typer.Option(
        "--fps", help="play the video at this many frames per second (default: its own, "
                      "else 30)", min=0.1, max=1000)] = None,
    render_scale: Annotated[int, typer.Option(
        "--render-scale", help="render at 1/K of the frames' size and composite the "
                               "upsampled layers over the full-size frame, as the studio "
                               "does while dragging (K must divide the size; 1: full size)",
        min=1, max=64)] = 2,
    unpaced: Annotated[bool, typer.Option(
        "--unpaced", help="take every video frame as fast as it renders (no wall clock, no "
                          "drops; deterministic)")] = False,
    loops: Annotated[int | None, typer.Option(
        "--loop", help="play the video this many times (0: until Ctrl-C; default: 0 with "
                       "the studio page, else 1)", min=0, max=1_000_000)] = None,
    max_frames: Annotated[int | None, typer.Option(
        "--max-frames", help="stop after this many composited frames", min=1,
        max=100_000_000)] = None,
    studio: Annotated[bool, typer.Option(
        "--studio/--no-studio", help="show the frames in the studio page (printed URL with "
                                     "its token)")] = True,
    host: Annotated[str, typer.Option("--host", help="studio address to bind")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", help="studio port (0: any free port)", min=0,
                                      max=65535)] = 8000,
    token: Annotated[str | None, typer.Option(
        "--token", help="the studio page's access token (default: $ARLIGHT_STUDIO_TOKEN, "
                        "else random)")] = None,
    record: Annotated[Path | None, typer.Option(
        "--record", help="keep the composites: a video (.mp4/.webm, at the composited "
                         "rate) or a folder of PNG frames; never an input or a user's "
                         "file")] = None,
    log: Annotated[Path | None, typer.Option(
        "--log", help="JSON lines, one per composited frame: capture and show times, "
                      "latency and stage times (ms), frames dropped before it, pose")] = None,
    threads: Annotated[int | None, typer.Option(
        "--threads", help="Dr.Jit threads (default: all cores)", min=1, max=1024)] = None,
) -> None:
    """Live AR: a printed marker tracked in every frame of a camera or a video,
    the virtual objects rendered by an interactive method, the composites shown
    in the studio page. Units: sizes in metres, --fps in frames per second, log
    times in milliseconds. Latency: from a frame's capture (a video's frame:
    its arrival time) to its composite handed to the page and the recorder.
    At the end: frames composited, frames per second, frames dropped (arrived
    while one rendered, never queued), latency p50/p95, stage medians.
    """
    from arlight.errors import InputError
    from arlight.live import sources
    from arlight.live.loop import LiveCompositor, MarkerTracker, run_live
    from arlight.live.setup import live_job, with_light_estimate
    from arlight.live.sources import CameraSource, VideoSource, WallClock
    from arlight.methods import RenderSettings
    from arlight.methods.spec import parse_option_pairs
    from arlight.scene.load import load_scene, render_settings_for

    if example:
        scene = scene or EXAMPLE["scene"]
        if camera is None:
            video = video or EXAMPLE["video"]
        calib = calib or EXAMPLE["calib"]
        marker = marker or str(EXAMPLE["marker"])
    if scene is None:
        raise InputError("give a scene file (or --example)", field="SCENE")
    if (video is None) == (camera is None):
        raise InputError("give exactly one of --video FILE and --camera INDEX",
                         field="--video")
    if calib is None:
        raise InputError("the marker's pose needs the camera's calibration", field="--calib")
    if marker is None:
        raise InputError("give the printed target to track", field="--marker")
    if depth is not None and camera is not None:
        raise InputError("depth frames go with a video (--video), not a camera",
                         field="--depth")
    if unpaced and camera is not None:
        raise InputError("a camera cannot be unpaced (it delivers at its own rate)",
                         field="--unpaced")
    if light is not None and light_server is not None:
        raise InputError("give --light or --light-server, not both", field="--light-server")
    if light_server is not None:
        from arlight.live.server_light import METHOD

        if method not in (None, METHOD):
            raise InputError(f"the light server's states light the {METHOD} method; got "
                             f"{method!r}", field="--method")
        method = METHOD
    pairs = parse_option_pairs(option or [])
    given = render_settings_for(scene, method, spp, None, seed, pairs)
    if method is None and given["method"] == "reference":  # live needs an interactive one
        given = render_settings_for(scene, "dir", spp, None, seed, pairs)
    name = given["method"]
    settings = RenderSettings(spp=given["spp"], seed=given["seed"],
                              max_depth=given["max_depth"], options=given["options"])
    sc = load_scene(scene)
    if light is not None:
        sc = with_light_estimate(sc, light)
    inputs = [Path(scene), Path(calib), *([Path(video)] if video is not None else []),
              *([Path(depth)] if depth is not None else []),
              *([Path(light)] if light is not None else [])]
    if record is not None:
        from arlight.live.record import check_record
        from arlight.sequence.build import sequence_inputs

        found = [*inputs, *(p for p in sequence_inputs(sc.raw, scene, _NoFrames())
                            if p != _NoFrames.path)]
        check_record(record, found)
    if log is not None:
        from arlight.output_guard import check_outputs

        check_outputs({"--log": log}, inputs, overwrite=False)
    if loops is None:
        loops = 0 if studio else 1
    if video is not None:
        src = VideoSource(video, loops=loops, fps=fps)
    else:
        assert camera is not None
        src = CameraSource(camera, size=(sc.camera.width, sc.camera.height))
    fps_in = src.fps if fps is None else float(fps)
    depths = None
    if depth is not None:
        assert isinstance(src, VideoSource)
        depths = sources.DepthFrames(depth, src.source.count, src.size, depth_units)
        depths.validate()
    try:
        job, calibration, spec = live_job(sc, src.size, name, settings, calib, marker,
                                          fps_in, threads, src.name,
                                          has_depth=depths is not None,
                                          render_scale=render_scale)
    except BaseException:
        if isinstance(src, CameraSource):
            src.close()  # the device is free again
        raise
    clock = WallClock()
    client = server_light = None
    if light_server is not None:
        client, server_light = _light_client(job, light_server, light_snapshot,
                                             server_public_key, light_wait, insecure)
    comp = LiveCompositor(job, MarkerTracker(calibration, spec, job.camera), clock,
                          server_light, depths)
    typer.echo(f"live: preparing {name} for {Path(scene).name} at {src.size[0]}×"
               f"{src.size[1]} ...")
    prep = comp.prepare()
    if video is not None:  # one frame rendered before the clock starts: kernels compiled
        from arlight.live.sources import Captured

        assert isinstance(src, VideoSource)
        comp(Captured(next(iter(src.source)), clock.now()))
    sinks = []
    feed = server = recorder = None
    if studio:
        from arlight.live.studio import LiveFeed
        from arlight.methods import get_method

        feed = LiveFeed(f"live: {src.name}", name, get_method(name).spec.description,
                        src.size)
        server = _serve(feed, host, port, token)
        typer.echo(f"arlight live: {server.url}  (Ctrl-C stops)")
        sinks.append(feed)
    if record is not None:
        from arlight.live.record import Recorder

        recorder = Recorder(record)
        sinks.append(recorder)
    if video is not None:
        assert isinstance(src, VideoSource)
        caps = (sources.unpaced(src.frames(), clock) if unpaced
                else sources.paced(src.frames(), fps_in, clock))
    else:
        assert isinstance(src, CameraSource)
        caps = src.captures(clock)
    # the log is written next to its place and renamed there at the end (never half-written)
    log_tmp = None if log is None else log.with_name(f".{log.name}.partial-{os.getpid()}")
    fh = open(log_tmp, "w", encoding="utf-8") if log_tmp else None  # noqa: SIM115
    ok = False
    summary = None
    try:
        summary = run_live(caps, comp, sinks, clock, fh, max_frames)
        summary.prepare_seconds = prep
        ok = True
    finally:
        if fh is not None and log is not None and log_tmp is not None:
            fh.close()
            if ok:
                from arlight.output_guard import record_written

                os.replace(log_tmp, log)
                record_written([log])
            else:
                log_tmp.unlink(missing_ok=True)
        out = None
        if recorder is not None:
            out = recorder.close(summary.fps if summary is not None and not unpaced
                                 else fps_in, ok)
        if server is not None:
            server.__exit__(None, None, None)
        if client is not None:
            client.close()
    assert summary is not None
    d = summary.as_dict()
    typer.echo(f"{name}: {d['frames']} frames composited in {d['seconds']:.1f} s, "
               f"{d['frames_per_second']:.2f} frames/s, {d['dropped']} dropped, "
               f"{d['lost']} without the marker; latency p50 {d['latency_ms_p50']:.0f} ms, "
               f"p95 {d['latency_ms_p95']:.0f} ms (prepare {prep:.1f} s)")
    typer.echo("stages (median ms): " + json.dumps(
        {k: round(v, 1) for k, v in d["stage_ms_median"].items()}))
    if server_light is not None:
        typer.echo(f"light server: {server_light.updates} states applied, "
                   f"{server_light.skipped} skipped (another number of objects)")
    if out is not None:
        typer.echo(f"recorded: {out}")


class _NoFrames:
    """A stand-in frame source for :func:`arlight.sequence.build.sequence_inputs` (the
    scene's referenced files only)."""

    path = Path("")
    files: list[Path] = []


def _light_client(job, endpoint: str, snapshot: str | None, key: Path | None, wait: float,
                  insecure: bool):
    """(client, ServerLight): subscribed to ``endpoint``, its first state received."""
    from arlight.lightserver import security
    from arlight.lightserver.client import LightClient
    from arlight.live.server_light import ServerLight

    pub = security.load_public(key, "--server-public-key") if key is not None else None
    try:
        client = LightClient(endpoint, snapshot, server_public_key=pub, insecure=insecure)
    except InputError as exc:
        raise InputError(exc.message, field="--light-server") from exc
    client.start()
    try:
        client.wait_for(1, timeout=wait)
        return client, ServerLight(job, client)
    except BaseException:
        client.close()
        raise


def _serve(feed, host: str, port: int, token: str | None):
    """The studio server on ``host:port`` in a background thread, serving ``feed``."""
    import errno

    from arlight.studio.server import BackgroundServer, resolve_token

    srv = BackgroundServer(feed, host=host, port=port, token=resolve_token(token))
    try:
        return srv.__enter__()
    except OSError as exc:
        raise InputError(f"cannot serve on {host}:{port}: {exc.strerror or exc}",
                         field="--port" if exc.errno == errno.EADDRINUSE
                         else "--host") from exc


__all__ = ["EXAMPLE", "live_command"]
