"""``arlight insert``: the command-line face of :mod:`arlight.insert.pipeline`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_SEED, MAX_SPP
from arlight.errors import InputError


def insert_command(
    photo: Annotated[Path, typer.Argument(help="photograph with the marker in view (PNG/JPEG "
                                          "or EXR/.hdr)")],
    calib: Annotated[Path, typer.Option("--calib", help="camera calibration: OpenCV "
                                        "FileStorage YAML/XML or JSON (K, dist, size)")],
    marker: Annotated[str, typer.Option("--marker", help="printed target: charuco:COLSxROWS:"
                                        "SQUARE_M:MARKER_M:DICT, aruco:SIDE_M:DICT[:ID] or a "
                                        ".toml file")],
    light: Annotated[str, typer.Option("--light", help="LightEstimate .json, HDR panorama "
                                       "(.hdr/.exr), rig .toml, or sun:DX,DY,DZ:E[:AMBIENT] "
                                       "(direction towards the sun, board frame, +Y up)")],
    obj: Annotated[Path, typer.Option("--object", help="the virtual object: a mesh (PLY, "
                                      "OBJ) or a model with its own PBR materials (glTF/GLB, "
                                      "USD/USDZ)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    at: Annotated[str, typer.Option("--at", help="X,Y,Z (m, board frame, +Y up) of the "
                                    "object's bottom centre; Y = 0 stands on the board")]
    = "0,0,0",
    scale: Annotated[float, typer.Option("--scale", help="uniform scale of the mesh")] = 1.0,
    rotate: Annotated[list[str] | None, typer.Option("--rotate", help="AX,AY,AZ,DEG rotation "
                      "after scaling (repeatable, applied in order)")] = None,
    color: Annotated[str, typer.Option("--color", help="R,G,B diffuse albedo of a mesh "
                                       "object in [0, 1] (models keep their materials)")]
    = "0.8,0.8,0.8",
    light_rotation: Annotated[float, typer.Option("--light-rotation", help="rotation of a "
                              "panorama or estimate about +Y relative to the board (deg)")]
    = 0.0,
    light_scale: Annotated[float, typer.Option("--light-scale", help="multiplier of the "
                           "light (exposure match between light capture and photo)")] = 1.0,
    plane_size: Annotated[str, typer.Option("--plane-size", help="X,Z extent of the "
                          "supporting plane (m), centred on the marker")] = "1.0,1.0",
    box: Annotated[list[str] | None, typer.Option("--box", help="extra real box "
                   "X,Y,Z:SX,SY,SZ[:R,G,B] (centre and sizes in m, board frame; "
                   "repeatable)")] = None,
    albedo: Annotated[str, typer.Option("--albedo", help="plane albedo: texture (per texel) "
                      "or median")] = "texture",
    method: Annotated[str, typer.Option("--method", "-m", help="registered method")]
    = "reference",
    spp: Annotated[int, typer.Option("--spp", help="samples per pixel", min=1,
                                     max=MAX_SPP)] = 64,
    seed: Annotated[int, typer.Option("--seed", help="random seed", min=0,
                                      max=MAX_SEED)] = 0,
    option: Annotated[list[str] | None, typer.Option("--option", help="method option "
                      "key=value (repeatable; `arlight methods NAME` lists them)")] = None,
    force: Annotated[bool, typer.Option("--force", help="run beyond the memory/time "
                                        "bounds")] = False,
) -> None:
    """Insert a virtual object into a photograph with a printed ChArUco board or ArUco marker.

    Writes OUT/scene.toml (editable; `arlight render OUT/scene.toml` renders it again),
    OUT/registration.json (pose, reprojection error, albedo) and OUT/render/ (layers and
    composite.png), as one set.
    """
    from arlight.bounds import check_estimate, estimate, image_size
    from arlight.insert.numbers import floats, number, rotation
    from arlight.insert.pipeline import (
        InsertRequest,
        check_insert_output,
        insert_inputs,
        prepare_inputs,
        run_insert,
    )
    from arlight.insert.proxy import parse_box
    from arlight.methods import RenderSettings, get_method
    from arlight.methods.spec import parse_option_pairs

    if albedo not in ("texture", "median"):
        raise InputError(f"expected texture or median, got {albedo!r}", field="--albedo")
    req = InsertRequest(photo=photo, calib=calib, marker=marker, light=light, object=obj,
                        at=floats(at, 3, "--at"),  # type: ignore[arg-type]
                        scale=number(scale, "--scale", 1e-6, 1e6),
                        rotate=[rotation(r) for r in rotate or []],
                        color=floats(color, 3, "--color", 0.0, 1.0),  # type: ignore[arg-type]
                        light_rotation_deg=number(light_rotation, "--light-rotation",
                                                  -3600.0, 3600.0),
                        light_scale=number(light_scale, "--light-scale", 0.0, 1e9,
                                           lo_open=True),
                        plane_size=floats(plane_size, 2, "--plane-size"),  # type: ignore[arg-type]
                        boxes=[parse_box(b) for b in box or []], albedo_mode=albedo)
    _, calibration, lights = prepare_inputs(req)
    if not photo.is_file():
        raise InputError("photo not found", file=str(photo), field="PHOTO")
    # the cost from the photo's header (or the calibration's size), before decoding it
    from arlight.io.images import is_hdr_path, read_hdr, read_ldr

    size = image_size(photo)
    if size is None and is_hdr_path(photo):
        size = calibration.size
    if size is None:  # a header we cannot parse: decoding reports what is wrong
        image = read_hdr(photo) if is_hdr_path(photo) else read_ldr(photo)
        size = image.shape[1], image.shape[0]
        del image
    w, h = size
    est = estimate(w, h, spp, paths=2, layers=14)
    check_estimate(est, f"rendering the {w}×{h} photo at {spp} spp", force)
    check_insert_output(out, insert_inputs(req, lights), int(est.output_bytes))
    # the method last among the checks: loading the methods costs seconds
    fn = get_method(method)
    settings = RenderSettings(spp=spp, seed=seed, progress=True,
                              options=parse_option_pairs(option or []))
    fn.spec.parse_options(settings.options)  # a bad option fails before any work
    result, layers = run_insert(req, out, method, settings)
    r = result.registration
    typer.echo(f"pose: {r.corners} corners, reprojection error {r.reprojection_px:.3f} px "
               f"mean, {r.reprojection_max_px:.3f} px max", err=True)
    typer.echo("albedo (median): " + ", ".join(f"{a:.3f}" for a in result.albedo.median),
               err=True)
    typer.echo(f"scene: {out}/scene.toml  composite: {out}/render/composite.png", err=True)
