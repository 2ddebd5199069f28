"""``arlight light atlas``: one near-field server update (Rohmer 2015) → a light JSON.

    arlight light atlas SCENE --cameras cams.toml -o vals.json [--tau 0.9 --vals 16]

SCENE is the proxy scene (real shapes: the reconstructed model; virtual shapes: the objects
that get an SH block each). A camera of the rig that names an ``image`` is read from it
(linear HDR, EXR / Radiance); the others are rendered (synthetic capture) in ``--world``
(default: SCENE itself) with ``--spp`` paths per pixel. Without ``--cameras`` an automatic
rig of fisheyes inside the proxy's bounds is used. Bad input raises
:class:`~arlight.errors.InputError` naming the file or option (:func:`arlight.cli.main`: one
line, exit status 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.cli_options import Force

# Memory of the server per atlas texel (supersampled geometry, radiance, split, dilated
# atlases) and per rig pixel (an HDR image, its projection: rays, depths, weights).
BYTES_PER_TEXEL = 1024.0
BYTES_PER_RIG_PIXEL = 256.0


def atlas_estimate(atlas_resolution: int, cameras: list[tuple[int, int, bool]], spp: int):
    """Memory/time :class:`~arlight.bounds.Estimate` of one server update: the atlas, the
    rig's images (``(width, height, rendered)`` per camera: rendered ones are a synthetic
    capture of ``spp`` paths per pixel)."""
    from arlight.bounds import Estimate, estimate, work_estimate

    texels = float(atlas_resolution) ** 2
    pixels = sum(float(w) * float(h) for w, h, _ in cameras)
    base = work_estimate(BYTES_PER_TEXEL * texels + BYTES_PER_RIG_PIXEL * pixels,
                         operations=400.0 * texels + 200.0 * pixels)
    mem, secs = base.memory_bytes, base.seconds
    for w, h, rendered in cameras:
        if rendered:
            e = estimate(w, h, spp, paths=1, layers=1)
            mem, secs = max(mem, base.memory_bytes + e.memory_bytes), secs + e.seconds
    return Estimate(mem, secs, 0.0)


def _check_int(value: int, option: str, lo: int, hi: float) -> None:
    from arlight.errors import InputError

    if not lo <= value <= hi:
        raise InputError(f"expected {lo} to {hi:g}, got {value}", field=option)


def atlas(
    scene: Annotated[Path, typer.Argument(help="proxy scene file (TOML)")],
    output: Annotated[Path, typer.Option("-o", "--output", help="light JSON to write")
                      ] = Path("vals.json"),
    cameras: Annotated[Path | None, typer.Option(
        help="fisheye rig (cams.toml); default: six fisheyes inside the proxy's bounds")
    ] = None,
    world: Annotated[Path | None, typer.Option(
        help="scene whose real part the synthetic capture renders (default: SCENE)")] = None,
    tau: Annotated[float, typer.Option(help="direct share τ of the total intensity, [0, 1]")
                   ] = 0.6,  # split.DEFAULT_TAU (a command module imports no NumPy; tested)
    vals: Annotated[int, typer.Option(
        help="number of virtual area lights M (1 … the nearfield method's cap, 256)")] = 16,
    atlas_resolution: Annotated[int, typer.Option("--atlas", help="atlas side (texels)")
                                ] = 256,
    size: Annotated[int, typer.Option(help="side of the automatic rig's images (px)")
                    ] = 128,
    spp: Annotated[int, typer.Option(help="paths per pixel of synthetic captures")] = 32,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an existing output arlight did not write (never the "
        "scene, the rig or a file they reference)")] = False,
    force: Force = False,
) -> None:
    """Run one server update of the near-field pipeline and write the VALs and SH."""
    from arlight.bounds import check_estimate
    from arlight.errors import InputError
    from arlight.io.images import read_hdr
    from arlight.methods.nearfield import OPTIONS
    from arlight.nearfield.cameras import default_rig, load_rig, seeing_cameras
    from arlight.nearfield.capture import capture, real_scene
    from arlight.nearfield.lightfile import save_light
    from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings
    from arlight.nearfield.state import MAX_VALS
    from arlight.output_guard import check_outputs, record_written, referenced_files
    from arlight.scene.load import load_scene

    settings = NearFieldSettings(atlas_resolution=atlas_resolution, tau=tau, vals=vals)
    settings.check()
    # the caps of the nearfield method that renders the light (a light beyond them
    # could not be rendered; --vals 10^9 would silently give as many VALs as texels)
    _check_int(vals, "--vals", 1, MAX_VALS)
    _check_int(atlas_resolution, "--atlas", 16, OPTIONS["atlas_resolution"].max)
    _check_int(size, "--size", 8, OPTIONS["capture_size"].max)
    _check_int(spp, "--spp", 1, OPTIONS["capture_spp"].max)
    inputs = [f for p in (scene, cameras, world) if p is not None
              for f in referenced_files(p)]
    check_outputs({"--output": output}, inputs, overwrite=True)
    proxy = load_scene(scene)
    rig = load_rig(cameras) if cameras is not None else default_rig(proxy.world, size)
    inputs += [c.image for c in rig if c.image is not None]
    check_outputs({"--output": output}, inputs, overwrite=overwrite)
    check_estimate(atlas_estimate(atlas_resolution, [(*c.size, c.image is None)
                                                     for c in rig], spp),
                   f"the atlas of {scene.name}", force,
                   lower="--atlas, --size, --spp or the rig's image sizes",
                   field="--atlas")
    server = NearFieldServer(proxy.world, rig, settings)
    if cameras is None:  # automatic rig: keep the cameras that see the proxy
        server.cameras = seeing_cameras(rig, server.geometry, server.proxy_scene)
    src = load_scene(world).world if world is not None else proxy.world
    mi_scene = None
    images = []
    for k, cam in enumerate(server.cameras):
        if cam.image is not None:
            try:
                images.append(read_hdr(cam.image))
            except InputError:
                raise
            except Exception as exc:  # unreadable image: name it
                raise InputError(f"cannot read HDR image ({exc})", file=str(cam.image),
                                 field=f"camera {cam.name}.image") from exc
        else:
            mi_scene = mi_scene or real_scene(src)
            images.append(capture(mi_scene, cam, spp, 1000 * k))
    light = server.update(images)
    save_light(light, output, [s.name for s in proxy.world.virtual_shapes])
    record_written([output])
    st = server.stats
    total = sum(v for k, v in st.items() if k != "cube_maps")
    typer.echo(f"wrote {output}: {light.count} VALs, SH for {light.n_objects} objects "
               f"({len(server.cameras)} cameras, τ = {tau:g}); server update {total:.0f} ms")


__all__ = ["atlas", "atlas_estimate"]
