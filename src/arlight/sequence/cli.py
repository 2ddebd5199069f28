"""``arlight sequence SCENE --frames DIR|VIDEO --poses poses.txt -m METHOD -o OUT``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_SEED, MAX_SPP
from arlight.errors import InputError


def sequence_command(
    scene: Annotated[Path, typer.Argument(help="AR scene file: the world (proxy, virtual "
                                          "objects, lights) and the camera (intrinsics, "
                                          "transfer); its render table gives defaults")],
    frames: Annotated[Path, typer.Option("--frames", help="folder of images (natural name "
                                         "order) or a video file (mp4, mov, mkv, webm, ...)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder (rerun with the "
                                      "same inputs to resume)")],
    poses: Annotated[str, typer.Option("--poses", help="camera poses: a poses file "
                                       "(FRAME tx ty tz qx qy qz qw, or FRAME + 3×4 matrix; "
                                       "sparse frames are keyframes), a keyframes .toml, "
                                       "`scene` (the scene's camera in every frame) or "
                                       "`marker` (tracked per frame; needs --calib and "
                                       "--marker). See docs/sequence.md")] = "scene",
    objects: Annotated[Path | None, typer.Option("--objects", help="per-frame object "
                       "transforms: FRAME NAME tx ty tz qx qy qz qw lines, or a keyframes "
                       ".toml (arrays objects.NAME)")] = None,
    pose_axes: Annotated[str, typer.Option("--pose-axes", help="camera axes of the poses "
                         "file: opencv (x right, y down, z forward) or opengl (ARKit: y up, "
                         "z backward)")] = "opencv",
    calib: Annotated[Path | None, typer.Option("--calib", help="camera calibration for "
                     "--poses marker (OpenCV YAML/XML or JSON)")] = None,
    marker: Annotated[str | None, typer.Option("--marker", help="printed target for "
                      "--poses marker: charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT or "
                      "aruco:SIDE_M:DICT[:ID]")] = None,
    depth: Annotated[Path | None, typer.Option("--depth", help="folder of per-frame depth "
                     "images (for methods that need depth), one per frame")] = None,
    method: Annotated[str | None, typer.Option("--method", "-m", help="registered method "
                      "(default: the scene's render table, else reference)")] = None,
    spp: Annotated[int | None, typer.Option("--spp", help="samples per pixel", min=1,
                                            max=MAX_SPP)] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="seed of every frame (the same "
                    "random sequence each frame: no noise flicker)", min=0,
                    max=MAX_SEED)] = None,
    max_depth: Annotated[int | None, typer.Option("--max-depth", help="longest path in "
                         "vertices (-1 unlimited)")] = None,
    option: Annotated[list[str] | None, typer.Option("--option", help="method option "
                      "key=value (repeatable)")] = None,
    vary_seed: Annotated[bool, typer.Option("--vary-seed", help="a different seed per frame "
                         "(independent noise: flickers; for comparison)")] = False,
    layers: Annotated[bool, typer.Option("--layers", help="also write each frame's layers "
                      "(composite, mixed, delta, mask) as EXR under layers/")] = False,
    video: Annotated[str, typer.Option("--video", help="videos to encode at the end: mp4, "
                     "webm, mp4,webm or none")] = "mp4",
    fps: Annotated[float | None, typer.Option("--fps", help="frames per second of the video "
                   "(default: the input video's, else 24)", min=0.001, max=1000)] = None,
    ray: Annotated[str | None, typer.Option("--ray", help="render on Ray: `auto` starts a "
                   "local instance, HOST:PORT or ray://HOST:PORT joins a cluster")] = None,
    workers: Annotated[int | None, typer.Option("--workers", help="Ray tasks at once (local: "
                       "CPUs given to Ray; default all)", min=1, max=100000)] = None,
    threads: Annotated[int | None, typer.Option("--threads", help="Dr.Jit threads per Ray "
                       "worker (default: local CPUs / workers, 1 on a cluster)", min=1,
                       max=1024)] = None,
    split: Annotated[int, typer.Option("--split", help="render each frame in this many "
                     "parts of spp/split samples (separate Ray tasks), averaged; progressive "
                     "methods only", min=1, max=MAX_SPP)] = 1,
    render_scale: Annotated[int, typer.Option(
        "--render-scale", help="render at 1/K of the frames' size and composite the "
                               "upsampled layers over the full-size frames (K must divide "
                               "the size; 1: full size)", min=1, max=64)] = 1,
    restart: Annotated[bool, typer.Option("--restart", help="replace another sequence's "
                       "frames in OUT instead of refusing (nothing is removed before every "
                       "input is checked and the first new frame is rendered)")] = False,
    force: Annotated[bool, typer.Option("--force", help="run beyond the memory/time bounds "
                                        "(frames × resolution × spp)")] = False,
) -> None:
    """Render an AR video: every frame of a sequence, resumable, optionally on Ray."""
    import os

    from arlight.bounds import check_estimate, check_range, estimate
    from arlight.methods import RenderSettings
    from arlight.methods.spec import parse_option_pairs
    from arlight.scene.load import load_scene, render_settings_for
    from arlight.sequence.build import build_job, sequence_inputs
    from arlight.sequence.frames import FrameSource
    from arlight.sequence.runner import RunOptions, run_sequence, validate_depths
    from arlight.sequence.store import SequenceStore

    given = render_settings_for(scene, method, spp, max_depth, seed,
                                parse_option_pairs(option or []))
    settings = RenderSettings(spp=given["spp"], seed=given["seed"],
                              max_depth=given["max_depth"], options=given["options"])
    videos = tuple(v.strip().lower() for v in video.split(",") if v.strip())
    if videos == ("none",):
        videos = ()
    bad = [v for v in videos if v not in ("mp4", "webm")]
    if bad:
        raise InputError(f"unknown video format {bad[0]!r}; expected mp4, webm or none",
                         field="--video")
    if fps is not None:
        check_range(fps, "--fps", 0.001, 1000)
    sc = load_scene(scene)
    source = FrameSource(frames)
    w, h = source.size
    est = estimate(w, h, settings.spp, paths=2, layers=4 if layers else 1,
                   renders=source.count)
    check_estimate(est, f"rendering {source.count} frames of {w}×{h} at {settings.spp} spp",
                   force)
    depths = None
    if depth is not None:
        depths = FrameSource(depth).files
        if not depths:
            raise InputError("expected a folder of depth images", file=str(depth),
                             field="--depth")
    # every frame and depth image decoded, and the output checked against the inputs,
    # before the method is loaded (seconds) or anything is written
    source.validate()
    if depths is not None:
        validate_depths(depths, source.size)
    inputs = sequence_inputs(sc.raw, scene, source, depths, poses, objects, calib, marker)
    SequenceStore.check_paths(out, restart, inputs, videos)
    if threads is None and ray == "auto":
        threads = max(1, (os.cpu_count() or 1) // (workers or os.cpu_count() or 1))
    elif threads is None and ray is not None:
        threads = 1
    job = build_job(sc, source, given["method"], settings, poses=poses, objects=objects,
                    axes=pose_axes, calib=calib, marker=marker, fps=fps, vary_seed=vary_seed,
                    layers=layers, threads=threads if ray is not None else None,
                    split=split, render_scale=render_scale)
    job.test_hook = os.environ.get("ARLIGHT_TEST_SEQUENCE_HOOK") or None  # fault tests
    summary = run_sequence(job, source, out, RunOptions(ray=ray, workers=workers,
                                                        videos=videos, restart=restart),
                           depths=depths, inputs=inputs)
    d = summary.as_dict()
    per = d["frame_seconds"]
    per_text = (f"; per frame {per['median']:.3f} s median ({per['min']:.3f}–"
                f"{per['max']:.3f})" if per else "")
    typer.echo(f"{job.method}: {summary.frames} frames ({summary.rendered} rendered, "
               f"{summary.resumed} already done) in {summary.seconds:.1f} s on "
               f"{summary.backend}, {d['frames_per_second']:.2f} frames/s{per_text}")
    for v in summary.videos:
        typer.echo(f"video: {v}")
    typer.echo(f"frames: {Path(out) / 'frames'}  summary: {Path(out) / 'summary.json'}")


__all__ = ["sequence_command"]
