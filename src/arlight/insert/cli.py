"""``arlight insert``: the command-line face of :mod:`arlight.insert.pipeline`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_SEED, MAX_SPP
from arlight.errors import InputError


def _floats(text: str, n: int, field: str) -> tuple[float, ...]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError as exc:
        raise InputError(f"cannot parse {text!r} ({exc})", field=field) from exc
    if len(v) != n:
        raise InputError(f"expected {n} numbers separated by commas, got {text!r}",
                         field=field)
    return v


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
    obj: Annotated[Path, typer.Option("--object", help="mesh of the virtual object")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    at: Annotated[str, typer.Option("--at", help="X,Y,Z (m, board frame, +Y up) of the "
                                    "object's bottom centre; Y = 0 stands on the board")]
    = "0,0,0",
    scale: Annotated[float, typer.Option("--scale", help="uniform scale of the mesh")] = 1.0,
    rotate: Annotated[list[str] | None, typer.Option("--rotate", help="AX,AY,AZ,DEG rotation "
                      "after scaling (repeatable, applied in order)")] = None,
    color: Annotated[str, typer.Option("--color", help="R,G,B diffuse albedo of the object "
                                       "in [0, 1]")] = "0.8,0.8,0.8",
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
    from arlight.bounds import check_estimate, estimate
    from arlight.insert.pipeline import INSERT_FILES, InsertRequest, prepare_inputs, run_insert
    from arlight.insert.proxy import parse_box
    from arlight.io.images import is_hdr_path, read_hdr, read_ldr
    from arlight.methods import RenderSettings, get_method
    from arlight.methods.spec import parse_option_pairs
    from arlight.outputs_atomic import check_output_dir

    if albedo not in ("texture", "median"):
        raise InputError(f"expected texture or median, got {albedo!r}", field="--albedo")
    rot = [_floats(r, 4, "--rotate") for r in rotate or []]
    req = InsertRequest(photo=photo, calib=calib, marker=marker, light=light, object=obj,
                        at=_floats(at, 3, "--at"), scale=scale, rotate=rot,  # type: ignore[arg-type]
                        color=_floats(color, 3, "--color"),  # type: ignore[arg-type]
                        light_rotation_deg=light_rotation, light_scale=light_scale,
                        plane_size=_floats(plane_size, 2, "--plane-size"),  # type: ignore[arg-type]
                        boxes=[parse_box(b) for b in box or []], albedo_mode=albedo)
    fn = get_method(method)
    settings = RenderSettings(spp=spp, seed=seed, progress=True,
                              options=parse_option_pairs(option or []))
    fn.spec.parse_options(settings.options)  # a bad option fails before any work
    prepare_inputs(req)
    image = read_hdr(photo) if is_hdr_path(photo) else read_ldr(photo)
    h, w = image.shape[:2]
    est = estimate(w, h, spp, paths=2, layers=14)
    check_estimate(est, f"rendering {w}×{h} at {spp} spp", force)
    inputs = [photo, calib, obj] + ([Path(light)] if Path(light).is_file() else [])
    check_output_dir(out, INSERT_FILES, int(est.output_bytes), inputs)
    result, layers = run_insert(req, out, method, settings)
    r = result.registration
    typer.echo(f"pose: {r.corners} corners, reprojection error {r.reprojection_px:.3f} px "
               f"mean, {r.reprojection_max_px:.3f} px max", err=True)
    typer.echo("albedo (median): " + ", ".join(f"{a:.3f}" for a in result.albedo.median),
               err=True)
    typer.echo(f"scene: {out}/scene.toml  composite: {out}/render/composite.png", err=True)
