"""``arlight light atlas``: one near-field server update (Rohmer 2015) → a light JSON.

    arlight light atlas SCENE --cameras cams.toml -o vals.json [--tau 0.9 --vals 16]

SCENE is the proxy scene (real shapes: the reconstructed model; virtual shapes: the objects
that get an SH block each). A camera of the rig that names an ``image`` is read from it
(linear HDR, EXR / Radiance); the others are rendered (synthetic capture) in ``--world``
(default: SCENE itself) with ``--spp`` paths per pixel. Without ``--cameras`` an automatic
rig of fisheyes inside the proxy's bounds is used. Bad input exits with status 2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _fail(message: str) -> None:
    typer.echo(f"error: {' '.join(str(message).split())}", err=True)
    raise typer.Exit(code=2)


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
                   ] = 0.6,
    vals: Annotated[int, typer.Option(help="number of virtual area lights M (>= 1)")] = 16,
    atlas_resolution: Annotated[int, typer.Option("--atlas", help="atlas side (texels)")
                                ] = 256,
    size: Annotated[int, typer.Option(help="side of the automatic rig's images (px)")
                    ] = 128,
    spp: Annotated[int, typer.Option(help="paths per pixel of synthetic captures")] = 32,
) -> None:
    """Run one server update of the near-field pipeline and write the VALs and SH."""
    from arlight.errors import ArlightError
    from arlight.io.images import read_hdr
    from arlight.nearfield.cameras import default_rig, load_rig, seeing_cameras
    from arlight.nearfield.capture import capture, real_scene
    from arlight.nearfield.lightfile import save_light
    from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings
    from arlight.scene.load import load_scene

    try:
        settings = NearFieldSettings(atlas_resolution=atlas_resolution, tau=tau, vals=vals)
        settings.check()
        if spp < 1 or size < 8:
            raise ArlightError(f"--spp must be >= 1 and --size >= 8, got {spp}, {size}")
        inputs = [p for p in (scene, cameras, world) if p is not None]
        for p in inputs:
            if p.resolve() == output.resolve():
                raise ArlightError(f"--output {output}: would overwrite the input {p}")
        if output.is_dir():
            raise ArlightError(f"--output {output}: is a folder, expected a file name")
        proxy = load_scene(scene)
        rig = load_rig(cameras) if cameras is not None else default_rig(proxy.world, size)
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
                except Exception as exc:  # unreadable image: name it
                    raise ArlightError(f"{cam.image}: cannot read HDR image ({exc})") from exc
            else:
                mi_scene = mi_scene or real_scene(src)
                images.append(capture(mi_scene, cam, spp, 1000 * k))
        light = server.update(images)
        save_light(light, output, [s.name for s in proxy.world.virtual_shapes])
    except (ArlightError, ValueError) as exc:
        _fail(str(exc))
    st = server.stats
    total = sum(v for k, v in st.items() if k != "cube_maps")
    typer.echo(f"wrote {output}: {light.count} VALs, SH for {light.n_objects} objects "
               f"({len(server.cameras)} cameras, τ = {tau:g}); server update {total:.0f} ms")


__all__ = ["atlas"]
