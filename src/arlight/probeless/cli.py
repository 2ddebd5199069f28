"""``arlight light probeless RGBD_DIR --poses FILE -o light.json`` (Gruber et al. 2014).

Reads an RGB-D sequence (:mod:`arlight.probeless.rgbd_io`), reconstructs it with Open3D's
TSDF (:mod:`arlight.probeless.reconstruct`), runs the per-frame transfer and light estimate
(:class:`arlight.probeless.pipeline.Pipeline`, variant ``--variant``) and writes

* ``-o light.json``: the :class:`~arlight.light.estimate.LightEstimate` fitted to the samples
  of all frames together (16 radiance SH, the dominant direction as main direction with zero
  irradiance, confidence = observable share of the coefficients); a scene uses it with
  ``[[lights]] type = "sh"`` and its ``sh.coefficients`` (see docs/methods/probeless.md);
* ``<stem>.frames.json`` next to it: one estimate per frame plus its conditioning, rays and
  times;
* optionally ``--mesh FILE.ply``: the reconstruction.

All input is checked before any work; an ill-conditioned light (a single plane, too few
normals) is refused with exit status 2 unless ``--allow-low-confidence``. Either every output
is written or none. Bad input raises :class:`~arlight.errors.InputError` naming the file or
option; :func:`arlight.cli.main` prints the one line and exits 2.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated

import typer

from arlight.cli_options import Force

# Memory per TSDF voxel (Open3D's UniformTSDFVolume: tsdf, weight, colour as doubles, plus
# the marching-cubes pass) and per pixel of a frame (colour float32 RGB, depth, the
# pipeline's per-frame planes); time per voxel and frame of the integration.
BYTES_PER_VOXEL = 48.0
BYTES_PER_FRAME_PIXEL = 64.0
MAX_RESOLUTION = 1024


def _outputs_and_inputs(rgbd_dir: Path, poses: Path | None, output: Path, frames_out: Path,
                        mesh: Path | None) -> tuple[dict, list[Path]]:
    """The planned outputs (field → path) and every input file (the whole RGB-D folder,
    the poses). An output inside the folder's colour or depth images would become a frame
    of the sequence: refused."""
    from arlight.errors import InputError
    from arlight.output_guard import folder_files
    from arlight.probeless.rgbd_io import image_dirs

    outputs = {"--output": output, "--output (per-frame file)": frames_out}
    if mesh is not None:
        outputs["--mesh"] = mesh
    for fld, path in outputs.items():
        real = Path(os.path.realpath(path))
        for d in image_dirs(rgbd_dir):
            if real.is_relative_to(Path(os.path.realpath(d))):
                raise InputError(f"is inside the image folder {d} of the RGB-D sequence; it "
                                 "would change the sequence (choose another path)",
                                 file=str(path), field=fld)
    return outputs, folder_files(rgbd_dir) + ([poses] if poses is not None else [])


def probeless_estimate(rgbd_dir: Path, resolution: int, max_frames: int | None):
    """Memory/time :class:`~arlight.bounds.Estimate` of a run, from the TSDF size and the
    frames' image headers (nothing is decoded)."""
    from arlight.bounds import image_size, work_estimate
    from arlight.probeless.rgbd_io import frame_files

    pixels, frames = 0.0, 0
    try:
        colours, _ = frame_files(rgbd_dir)
    except Exception:  # noqa: BLE001 - the reader reports a bad folder
        colours = []
    for c in colours[:max_frames]:
        size = image_size(c)
        if size is not None:
            pixels += float(size[0]) * float(size[1])
        frames += 1
    voxels = float(resolution) ** 3
    return work_estimate(BYTES_PER_VOXEL * voxels + BYTES_PER_FRAME_PIXEL * pixels,
                         operations=voxels * max(frames, 1) + 2000.0 * pixels,
                         output_bytes=voxels * 4.0)


def run(rgbd_dir: Path, poses: Path | None, output: Path, intrinsics: str | None = None,
        depth_scale: float = 1000.0, variant: str = "ART4", volume: float = 2.0,
        resolution: int = 268, albedo: float = 0.5, depth_trunc: float = 4.0,
        max_frames: int | None = None, mesh: Path | None = None,
        allow_low_confidence: bool = False, overwrite: bool = False,
        force: bool = False) -> dict:
    """The command's work; returns a summary. Raises :class:`~arlight.errors.InputError` on
    bad input (before writing anything): options, the outputs (:func:`arlight.output_guard.
    check_outputs`: never a file of the RGB-D folder or the poses; never an existing file
    arlight did not write unless ``overwrite``), the memory/time estimate (unless
    ``force``), then the frames."""
    import numpy as np

    from arlight.backend.mitsuba_scene import build_views
    from arlight.bounds import MAX_FRAMES, check_estimate
    from arlight.errors import InputError
    from arlight.io.images import atomic_write
    from arlight.output_guard import check_outputs, record_written
    from arlight.probeless.estimate import estimate_light
    from arlight.probeless.pipeline import VARIANTS, Pipeline, Settings
    from arlight.probeless.reconstruct import reconstruct
    from arlight.probeless.rgbd_io import read_sequence
    from arlight.scene.model import World

    if variant not in VARIANTS:
        raise InputError(f"expected one of {', '.join(VARIANTS)}, got {variant!r}",
                         field="--variant")
    for val, name, lo in ((volume, "--volume", 0.0), (albedo, "--albedo", 0.0),
                          (depth_trunc, "--depth-trunc", 0.0)):
        if not np.isfinite(val) or val <= lo:
            raise InputError(f"must be a finite number > {lo:g}, got {val}", field=name)
    for val, name, hi in ((volume, "--volume", 1e4), (depth_trunc, "--depth-trunc", 1e4),
                          (albedo, "--albedo", 1.0), (depth_scale, "--depth-scale", 1e9)):
        if not np.isfinite(val) or not 0 < val <= hi:
            raise InputError(f"must be a finite number in (0, {hi:g}], got {val}", field=name)
    if max_frames is not None and not 1 <= max_frames <= MAX_FRAMES:
        raise InputError(f"expected 1 to {MAX_FRAMES} frames, got {max_frames}",
                         field="--max-frames")
    if not 8 <= resolution <= MAX_RESOLUTION:
        raise InputError(f"expected 8 to {MAX_RESOLUTION} voxels, got {resolution}",
                         field="--resolution")
    frames_out = output.with_name(f"{output.stem}.frames.json")
    outputs, inputs = _outputs_and_inputs(rgbd_dir, poses, output, frames_out, mesh)
    check_outputs(outputs, inputs, overwrite=overwrite)
    check_estimate(probeless_estimate(rgbd_dir, resolution, max_frames),
                   f"probeless on {rgbd_dir.name}", force,
                   lower="--resolution or --max-frames", field="--resolution")
    frames = read_sequence(rgbd_dir, poses, intrinsics, depth_scale, max_frames)
    shape = reconstruct(frames, volume=volume,
                        resolution=resolution, depth_trunc=depth_trunc, albedo=albedo)
    world = World(shapes=[shape], lights=[])
    views = build_views(world)
    pipe = Pipeline(views, variant, Settings(), shapes=world.shapes)
    per_frame, obs = [], []
    for f in frames:
        res = pipe.process(f.camera, f.colour, f.depth, shade=False)
        per_frame.append((f, res))
        obs.append(res.observations)
    fit = estimate_light(np.concatenate([o[0] for o in obs]),
                         np.concatenate([o[1] for o in obs]),
                         np.concatenate([o[2] for o in obs]), ridge=Settings().ridge)
    if not fit.determined and not allow_low_confidence:
        raise InputError(fit.message + "; nothing written (--allow-low-confidence writes it "
                         "flagged)", file=str(rgbd_dir), field="light")
    est = fit.to_light_estimate(timestamp=frames[-1].timestamp)
    if not fit.determined:
        est.confidence = min(est.confidence, 0.1)
    doc = {"format": "arlight.probeless_frames", "version": 1, "variant": variant,
           "reconstruction": {"volume_m": volume, "resolution": resolution,
                              "triangles": int(len(shape.mesh.faces))},
           "frames": []}
    for f, res in per_frame:
        e = res.fit.to_light_estimate(timestamp=f.timestamp)
        doc["frames"].append({
            "name": f.name, "light": e.to_json(), "condition": res.fit.condition
            if np.isfinite(res.fit.condition) else None, "rank": res.fit.rank,
            "determined": res.fit.determined, "samples": res.fit.samples,
            "rays": res.stats["rays"], "time_rt_s": res.stats["time_rt"],
            "time_estimate_s": res.stats["time_estimate"]})
    written: list[Path] = []
    try:
        if mesh is not None:
            from arlight.probeless.reconstruct import open3d

            o3d = open3d()
            m = o3d.geometry.TriangleMesh(
                o3d.utility.Vector3dVector(shape.mesh.vertices.astype(np.float64)),
                o3d.utility.Vector3iVector(shape.mesh.faces.astype(np.int32)))
            with atomic_write(mesh, ".ply") as tmp:
                if not o3d.io.write_triangle_mesh(str(tmp), m):
                    raise InputError("cannot write the mesh", file=str(mesh), field="--mesh")
            written.append(mesh)
        with atomic_write(frames_out, ".json") as tmp:
            tmp.write_text(json.dumps(doc, indent=1))
        written.append(frames_out)
        est.save(output, protect=tuple(inputs))
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    record_written(written)
    return {"estimate": est, "fit": fit, "frames": len(frames), "frames_file": frames_out}


def probeless(
    rgbd_dir: Annotated[Path, typer.Argument(help="folder with color/ and depth/ images")],
    poses: Annotated[Path | None, typer.Option(
        help="camera-to-world poses: 'tx ty tz qx qy qz qw' lines or a Redwood .log")] = None,
    output: Annotated[Path, typer.Option("-o", "--output", help="light JSON to write")
                      ] = Path("light.json"),
    intrinsics: Annotated[str | None, typer.Option(
        help="fx,fy,cx,cy in pixels (default: RGBD_DIR/intrinsics.json)")] = None,
    depth_scale: Annotated[float, typer.Option(help="depth units per metre")] = 1000.0,
    variant: Annotated[str, typer.Option(help="RM | REG4 | REG8 | ART1 | ART4 | ART8")
                       ] = "ART4",
    volume: Annotated[float, typer.Option(help="TSDF cube edge (m); Gruber: 2")] = 2.0,
    resolution: Annotated[int, typer.Option(help="TSDF voxels per axis; Gruber: 268")] = 268,
    albedo: Annotated[float, typer.Option(help="assumed albedo of the real scene")] = 0.5,
    depth_trunc: Annotated[float, typer.Option(help="ignore depth beyond (m)")] = 4.0,
    max_frames: Annotated[int | None, typer.Option(help="use the first N frames")] = None,
    mesh: Annotated[Path | None, typer.Option(help="also write the reconstruction (PLY)")
                    ] = None,
    allow_low_confidence: Annotated[bool, typer.Option(
        help="write an undetermined light (flagged, confidence <= 0.1) instead of failing")
    ] = False,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace existing outputs arlight did not write (never a file "
        "of the RGB-D folder or the poses)")] = False,
    force: Force = False,
) -> None:
    """Probeless light estimate from an RGB-D sequence (Gruber et al. 2014): TSDF
    reconstruction, 10 cm radiance transfer, least-squares 16-coefficient SH."""
    out = run(rgbd_dir, poses, output, intrinsics, depth_scale, variant, volume,
              resolution, albedo, depth_trunc, max_frames, mesh, allow_low_confidence,
              overwrite, force)
    fit = out["fit"]
    typer.echo(f"wrote {output} and {out['frames_file']}: {out['frames']} frames, dominant "
               f"light toward {[round(float(x), 3) for x in fit.direction]}, rank "
               f"{fit.rank}/16, condition {fit.condition:.3g}")


__all__ = ["probeless", "run"]
