"""``arlight light``: estimate lights from a probe / map / fisheye image, and picture them.

Examples::

    arlight light estimate grace.hdr --kind equirect --lights 16 -o light.json
    arlight light estimate ball.exr --kind ball --ball-center 512,500 \\
        --ball-radius 480 -o light.json
    arlight light estimate sky.png --kind fisheye --fov 185 -o light.json
    arlight light show light.json -o light.png

Outputs are written to a temporary file and renamed, so a failed run leaves nothing. Bad
input raises :class:`~arlight.errors.InputError` naming the file or the option;
:func:`arlight.cli.main` prints it on one line and exits 2. ``light probeless`` and
``light atlas`` live in their own packages and are mounted on this group by
:mod:`arlight.cli`. The heavy modules (numpy, the estimators, matplotlib) are imported by the
commands, not here: ``import arlight.cli`` stays cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from arlight.bounds import MAX_LIGHTS, MAX_SH_HEIGHT, MAX_SH_ORDER
from arlight.cli_options import Force
from arlight.errors import InputError

if TYPE_CHECKING:
    import numpy as np

    from arlight.light.estimate import LightEstimate

KINDS = ("equirect", "probe", "ball", "fisheye")

app = typer.Typer(
    help="Light estimation: SH, environment maps, probes, fisheye images, light extraction.",
    no_args_is_help=True,
    add_completion=False,
)


def _check_number(value: float | None, option: str, lo: float, hi: float,
                  lo_open: bool = True) -> None:
    if value is None:
        return
    if not math.isfinite(value) or (value <= lo if lo_open else value < lo) or value > hi:
        raise InputError(f"expected a finite number in {'(' if lo_open else '['}"
                         f"{lo:g}, {hi:g}], got {value}", field=option)


def _check_choice(value: str, option: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise InputError(f"expected one of {', '.join(choices)}, got {value!r}", field=option)


def _check_count(value: int, option: str, lo: int, hi: int, unit: str = "") -> None:
    if not lo <= value <= hi:
        raise InputError(f"expected {lo} to {hi}{unit}, got {value}", field=option)


def _check_output(output: Path, inputs: list[Path], option: str = "--output",
                  overwrite: bool = True) -> None:
    """The output file (:func:`arlight.output_guard.check_outputs`): not an input, not a
    folder or dangling symlink, its folder writable, and — unless ``overwrite`` — not an
    existing file arlight did not write. Called with ``overwrite=True`` before the inputs
    are read (their errors come first), then with the user's choice before any work."""
    from arlight.output_guard import check_outputs

    check_outputs({option: output}, [p for p in inputs if p is not None], overwrite=overwrite)


# Memory of estimating from (or picturing) an image, per pixel: the float32 RGB image as
# read, its equirect resampling, luminance and clipped SH planes, the map kept for writing.
BYTES_PER_MAP_PIXEL = 96.0


def check_image_bounds(images: list[Path], force: bool, height: int | None = None) -> None:
    """Refuse, before reading them, images whose processing would exceed the memory/time
    bounds (:func:`arlight.bounds.check_estimate`; sizes from the headers) unless
    ``force``."""
    from arlight.bounds import check_estimate, image_size, work_estimate

    pixels = 0.0
    for img in images:
        size = image_size(img)
        if size is not None:
            pixels += float(size[0]) * float(size[1])
    if height is not None:
        pixels += 2.0 * height * height
    est = work_estimate(BYTES_PER_MAP_PIXEL * pixels, operations=200.0 * pixels,
                        output_bytes=12.0 * pixels)
    names = ", ".join(p.name for p in images)
    check_estimate(est, f"reading {names}", force, lower="the image size (or --height)",
                   field="--force")


def _parse_vec(text: str | None, option: str, n: int) -> tuple[float, ...] | None:
    """``'a,b[,c]'`` -> ``n`` finite floats (None when the option was not given)."""
    if text is None:
        return None
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != n or not all(math.isfinite(x) for x in v):
        what = "cx,cy in pixels" if n == 2 else "x,y,z (world, +Y up)"
        raise InputError(f"expected {what}, got {text!r}", field=option)
    return v


def ball_pose(look: str | None, up: str | None) -> np.ndarray | None:
    """``world_from_camera`` (OpenCV axes) of the camera photographing a mirror ball, from
    the world direction it looks along and its up direction; None: the default pose
    (looking along world -Z, +Y up)."""
    import numpy as np

    if look is None and up is None:
        return None
    z = np.array(_parse_vec(look, "--ball-look", 3) or (0.0, 0.0, -1.0))
    u = np.array(_parse_vec(up, "--ball-up", 3) or (0.0, 1.0, 0.0))
    if np.linalg.norm(z) == 0 or np.linalg.norm(u) == 0:
        raise InputError("directions must not be zero", field="--ball-look/--ball-up")
    z = z / np.linalg.norm(z)
    x = np.cross(z, u)
    if np.linalg.norm(x) < 1e-6:
        raise InputError("the up direction is parallel to the view",
                         field="--ball-look/--ball-up")
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)  # columns: right, down, forward


# A mirror ball compresses its rim: a direction at angle a from the one reflected back to
# the camera shows at radius sin(a/2), so one pixel spans 1/cos(a/2) times the angle it
# spans at the centre. Beyond this stretch the reflection is treated as unseen (the blind
# cone behind the ball; it also holds the ball's silhouette edge, mixed with background).
BALL_MAX_STRETCH = 4.0


def ball_seen_half_angle(max_stretch: float = BALL_MAX_STRETCH) -> float:
    """Largest angle (rad) from the direction back to the camera that a mirror ball shows
    with a pixel footprint at most ``max_stretch`` x the centre's: ``2 acos(1/stretch)``."""
    import numpy as np

    return 2.0 * float(np.arccos(1.0 / max_stretch))


def _observed_fraction(seen: np.ndarray) -> float:
    """Fraction of the sphere covered by an equirect validity mask (solid-angle weighted)."""
    import numpy as np

    from arlight.sphere import envmap as E

    om = E.equirect_solid_angle(seen.shape[0], seen.shape[1])
    return float((om * seen).sum() / (4 * np.pi))


def _fisheye_seen(cam, height: int = 256) -> np.ndarray:
    """Equirect mask of the directions a fisheye camera sees inside its image."""
    from arlight.sphere import envmap as E

    xy, valid = cam.project(E.equirect_directions(height))
    w, h = cam.size
    return valid & (xy[..., 0] >= 0) & (xy[..., 0] <= w) & (xy[..., 1] >= 0) & (xy[..., 1] <= h)


def _return_freed_memory() -> None:
    """Hand freed heap memory back to the OS (glibc ``malloc_trim``; a no-op elsewhere).

    The extraction's temporary planes are freed before the map is written, but glibc keeps
    the space of smaller blocks in its heap; without this, writing the HDR map (Mitsuba
    copies it) would stack on top of that retained memory (~0.8 map sizes on a 4k map)."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        ctypes.CDLL(name).malloc_trim(0)
    except (OSError, AttributeError, TypeError):
        pass


# LDR input: a pixel with a channel at the top code value is clipped; this fraction of the
# observed pixels being clipped makes the estimate warn that the light is underestimated.
CLIPPED_WARN_FRACTION = 0.01


@dataclass
class Environment:
    """An input turned into equirect maps: ``map`` (what was observed, unseen = 0),
    ``confidence`` (observed fraction of the sphere), ``sh_map`` (the map for the SH
    remainder when it differs: the mirrored fisheye capture) and ``warnings``."""

    map: np.ndarray
    confidence: float
    sh_map: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)


def load_environment(image: Path, kind: str, height: int | None = None,
                     ball_center: str | None = None, ball_radius: float | None = None,
                     fisheye_calib: Path | None = None, fov: float | None = None,
                     mirror_lower: bool = True, ball_look: str | None = None,
                     ball_up: str | None = None) -> Environment:
    """Read ``image`` of ``kind`` into an :class:`Environment`.

    ``fov`` (degrees): the fisheye field of view when given explicitly; None keeps the
    calibration file's (180 for an uncalibrated equidistant lens)."""
    if kind not in KINDS:
        raise InputError(f"expected one of {', '.join(KINDS)}, got {kind!r}", field="--kind")
    import numpy as np

    from arlight.io.images import is_hdr_path, read_linear
    from arlight.sphere import envmap as E
    from arlight.sphere.fisheye import FisheyeCamera, load_camera

    if image.is_dir():
        raise InputError("is a folder, expected an image file", file=str(image))
    if kind in ("equirect", "probe") and not is_hdr_path(image):
        raise InputError(f"an {kind} environment map must be HDR (.exr/.hdr/.pfm); an "
                         "8/16-bit picture holds display values clipped at white, not "
                         "radiance", file=str(image))
    _check_number(fov, "--fov", 0.0, 360.0)
    _check_number(ball_radius, "--ball-radius", 0.0, 1e6)
    pose = ball_pose(ball_look, ball_up) if kind == "ball" else None
    img = read_linear(image)
    H, W = img.shape[:2]
    if np.any(img < 0):
        raise InputError(f"{int(np.count_nonzero(img < 0))} negative values; radiance must "
                         "be >= 0", file=str(image))
    warnings = []
    if not is_hdr_path(image):
        clipped = float(np.mean(img.max(axis=-1) >= 1.0 - 1e-6))
        if clipped > CLIPPED_WARN_FRACTION:
            warnings.append(f"{image}: {100 * clipped:.1f} % of the pixels are clipped at "
                            "white (LDR input): the light sources are underestimated; use "
                            "an HDR capture or an exposure bracket")
    if kind == "equirect":
        if W != 2 * H:
            raise InputError(f"an equirect map must be 2:1, got {W}x{H}", file=str(image))
        m = img if height in (None, H) else E.resize_equirect(img, height)
        return Environment(m, 1.0, None, warnings)
    if kind == "probe":
        if W != H:
            raise InputError(f"an angular light probe must be square, got {W}x{H}",
                             file=str(image))
        return Environment(E.to_equirect(img, "angular", height=height), 1.0, None, warnings)
    if kind == "ball":
        center = _parse_vec(ball_center, "--ball-center", 2)
        if center is None or ball_radius is None or ball_radius <= 0:
            raise InputError("--kind ball needs --ball-center cx,cy and --ball-radius (pixels)",
                             field="--ball-center")
        cx, cy = center
        tol = 1.0
        if (cx - ball_radius < -tol or cy - ball_radius < -tol
                or cx + ball_radius > W + tol or cy + ball_radius > H + tol):
            raise InputError(f"the ball (centre {cx:g},{cy:g}, radius {ball_radius:g} px) is "
                             f"not inside the {W}x{H} image {image}",
                             field="--ball-center/--ball-radius")
        m = E.to_equirect(img, "ball", height=height, center=center, radius=ball_radius,
                          world_from_camera=pose)
        rot = np.diag([1.0, -1.0, -1.0]) if pose is None else pose
        back = -rot[:, 2]  # the direction reflected straight back to the camera
        seen = E.equirect_directions(m.shape[0]) @ back >= np.cos(ball_seen_half_angle())
        m[~seen] = 0.0
        return Environment(m, _observed_fraction(seen), None, warnings)
    if fisheye_calib is not None:
        try:
            cam = load_camera(fisheye_calib, fov_deg=fov)
        except InputError as exc:  # the calibration file given by --fisheye-calib
            raise InputError(exc.message, file=exc.file or str(fisheye_calib),
                             field=exc.field or "--fisheye-calib") from exc
        if cam.size != (W, H):
            raise InputError(f"image is {W}x{H} but {fisheye_calib} is for "
                             f"{cam.size[0]}x{cam.size[1]}", file=str(image))
    else:
        cam = FisheyeCamera.equidistant((W, H), fov_deg=180.0 if fov is None else fov)
    m = E.to_equirect(img, "fisheye", height=height, camera=cam)
    mirrored = E.mirror_lower_hemisphere(m) if mirror_lower else None
    return Environment(m, _observed_fraction(_fisheye_seen(cam)), mirrored, warnings)


@app.command()
def estimate(
    image: Annotated[Path, typer.Argument(help="HDR (.hdr/.exr) or LDR image")],
    output: Annotated[Path, typer.Option("-o", "--output", help="light JSON to write")] = Path(
        "light.json"),
    kind: Annotated[str, typer.Option(help="equirect | probe (Debevec angular) | ball | "
                                           "fisheye")] = "equirect",
    lights: Annotated[int, typer.Option(
        help="most lights to extract (0: SH only); 'regions' returns one per source found, "
             "up to this cap")] = 16,
    sh_order: Annotated[int, typer.Option(help="SH order L ((L+1)^2 coefficients)")] = 2,
    method: Annotated[str, typer.Option(
        help="regions (one light per connected highlight) | median_cut | variance")
    ] = "regions",
    threshold: Annotated[float | None, typer.Option(
        help="highlight luminance threshold (default 4x the mean)")] = None,
    height: Annotated[int | None, typer.Option(help="equirect height to work at")] = None,
    ball_center: Annotated[str | None, typer.Option(help="mirror ball centre 'cx,cy' (px)")
                           ] = None,
    ball_radius: Annotated[float | None, typer.Option(help="mirror ball radius (px)")] = None,
    ball_look: Annotated[str | None, typer.Option(
        help="mirror ball: world direction 'x,y,z' the camera looks along (default 0,0,-1)")
    ] = None,
    ball_up: Annotated[str | None, typer.Option(
        help="mirror ball: the camera's up direction 'x,y,z' in the world (default 0,1,0)")
    ] = None,
    fisheye_calib: Annotated[Path | None, typer.Option(
        help="fisheye calibration: OCamCalib calib_results.txt, OpenCV .yml/.xml or JSON")
    ] = None,
    fov: Annotated[float | None, typer.Option(
        help="fisheye field of view (deg); default: the calibration's, else 180")] = None,
    mirror_lower: Annotated[bool, typer.Option(
        help="fisheye: mirror the upper hemisphere into the lower (Kan)")] = True,
    layout: Annotated[str, typer.Option(help="arlight | arcore | arkit | webxr")] = "arlight",
    sh_convention: Annotated[str, typer.Option(
        help="webxr layout: SH signs for three.js (threejs) or as Chrome passes ARCore's "
             "through (arcore)")] = "threejs",
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an existing output arlight did not write (never an "
        "input)")] = False,
    force: Force = False,
) -> None:
    """Estimate a LightEstimate (main light, extra lights, SH remainder) from an image."""
    import numpy as np

    from arlight.light.estimate import LAYOUTS, METHODS, SH_CONVENTIONS, LightEstimate

    _check_choice(layout, "--layout", LAYOUTS)
    _check_choice(sh_convention, "--sh-convention", SH_CONVENTIONS)
    _check_choice(method, "--method", METHODS)
    _check_count(lights, "--lights", 0, MAX_LIGHTS)
    _check_count(sh_order, "--sh-order", 0, MAX_SH_ORDER)
    if height is not None:
        _check_count(height, "--height", 2, MAX_SH_HEIGHT, " pixels")
    _check_number(threshold, "--threshold", 0.0, 1e30)
    inputs = [image] + ([fisheye_calib] if fisheye_calib is not None else [])
    _check_output(output, inputs)
    if image.is_file():
        check_image_bounds([image], force, height)
    env = load_environment(image, kind, height, ball_center, ball_radius, fisheye_calib,
                           fov, mirror_lower, ball_look, ball_up)
    _check_output(output, inputs, overwrite=overwrite)
    for w in env.warnings:
        typer.echo(f"warning: {w}", err=True)
    est = LightEstimate.from_envmap(env.map, n_lights=lights, sh_order=sh_order,
                                    method=method, threshold=threshold,
                                    confidence=env.confidence, sh_map=env.sh_map)
    del env
    _return_freed_memory()
    est.save(output, layout=layout, protect=tuple(inputs), sh_convention=sh_convention)
    share = est.explicit_fraction or 0.0
    typer.echo(f"wrote {output}: main light toward {np.round(est.main_direction, 3).tolist()}"
               f" + {len(est.lights)} more; the explicit lights hold {100 * share:.1f} % of "
               f"the map's energy; SH order {sh_order}; confidence {est.confidence:.2f}")


def _tonemap(img: np.ndarray) -> np.ndarray:
    import numpy as np

    scale = np.percentile(img, 99.0) or 1.0
    return np.clip(img / scale, 0, 1) ** (1 / 2.2)


def _irradiance_sphere(est: LightEstimate, size: int = 160) -> np.ndarray:
    """A white Lambertian sphere seen from +Z (radiance E/pi), black outside."""
    import numpy as np

    xs = (np.arange(size) + 0.5) / size * 2 - 1
    X, Y = np.meshgrid(xs, -xs)
    r2 = X**2 + Y**2
    inside = r2 <= 1
    n = np.stack([X, Y, np.sqrt(np.clip(1 - r2, 0, None))], axis=-1)
    out = np.zeros((size, size, 3))
    out[inside] = est.irradiance(n[inside]) / np.pi
    return out


# ``show``: a light's circle has an area (points^2) proportional to its power, this many
# points^2 for the most powerful light (the main light is red, the others yellow).
CIRCLE_AREA_MAX = 400.0


def circle_areas(powers: np.ndarray) -> np.ndarray:
    """Marker areas (points^2) proportional to ``powers`` (luminance W/m^2): the most
    powerful light gets :data:`CIRCLE_AREA_MAX`, a light of half its power half the area."""
    import numpy as np

    p = np.clip(np.asarray(powers, np.float64), 0.0, None)
    top = p.max(initial=0.0)
    return CIRCLE_AREA_MAX * p / top if top > 0 else np.zeros_like(p)


def sh_panel(recon: np.ndarray) -> tuple[np.ndarray, bool]:
    """What ``show`` draws for an SH reconstruction ``(H, W, 3)``: ``(tone-mapped RGB,
    False)`` when it is non-negative, else ``(signed luminance (H, W), True)`` for a
    diverging colour map centred on 0, so negative radiance is shown, not clipped."""
    from arlight.sphere import sh as SH

    lum = recon @ SH.LUMINANCE
    if lum.min() < 0:
        return lum, True
    return _tonemap(recon), False


def render_picture(est: LightEstimate, path: Path, title: str = "") -> Path:
    """Three panels: map + lights, SH reconstruction, irradiance sphere (PNG, atomic).

    The SH reconstruction is shown as colour when it is non-negative everywhere; when the
    truncated SH rings below zero (negative radiance), its luminance is shown with a
    diverging colour map centred on 0 (blue < 0 < red) instead of clipping it."""
    import matplotlib
    import numpy as np

    from arlight.io.images import atomic_write
    from arlight.light.extract import ExtractedLight
    from arlight.sphere import envmap as E
    from arlight.sphere import sh as SH

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    order = SH.order_of(est.sh.shape[0])
    recon = SH.sh_to_equirect(est.total_sh(max(order, 2)), 128)
    env = est.hdr_map if est.hdr_map is not None else recon
    if env.shape[0] > 512:  # a picture needs no more; keeps show cheap on 4k maps
        env = E.resize_equirect(env, 512)
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6),
                             gridspec_kw={"width_ratios": [2, 2, 1]})
    ax = axes[0]
    ax.imshow(_tonemap(np.clip(env, 0, None)), extent=(0, 1, 1, 0), aspect="auto")
    all_lights = [ExtractedLight(est.main_direction, est.main_irradiance), *est.lights]
    powers = np.array([lt.irradiance @ SH.LUMINANCE for lt in all_lights])
    areas = circle_areas(powers)
    for i, (lt, a) in reversed(list(enumerate(zip(all_lights, areas, strict=True)))):
        x, y = E.direction_to_equirect(lt.direction[None], 1, 1)[0]
        ax.scatter([x % 1], [y], s=a, facecolors="none",
                   edgecolors="red" if i == 0 else "yellow", linewidths=1.5)
    ax.set_title(f"map + {len(all_lights)} lights (red: main; circle area ∝ power)")
    ax.set_xlabel("u")
    ax.set_ylabel("v")
    panel, diverging = sh_panel(recon)
    if diverging:
        lim = float(np.abs(panel).max()) or 1.0
        im = axes[1].imshow(panel, extent=(0, 1, 1, 0), aspect="auto", cmap="RdBu_r",
                            norm=TwoSlopeNorm(0.0, -lim, lim))
        fig.colorbar(im, ax=axes[1], fraction=0.04, label="luminance (< 0: SH ringing)")
        axes[1].set_title(f"SH reconstruction, luminance (order {max(order, 2)}; "
                          f"min {panel.min():.3g} < 0)")
    else:
        axes[1].imshow(panel, extent=(0, 1, 1, 0), aspect="auto")
        axes[1].set_title(f"SH reconstruction (order {max(order, 2)}, lights folded in)")
    axes[2].imshow(_tonemap(_irradiance_sphere(est)))
    axes[2].set_title("irradiance E/pi (from +Z)")
    axes[2].axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        with atomic_write(path, ".png") as tmp:
            fig.savefig(tmp, format="png", dpi=90)
        return path
    finally:
        plt.close(fig)


@app.command()
def show(
    source: Annotated[Path, typer.Argument(help="light JSON, or an image to estimate from")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG to write")] = Path(
        "light.png"),
    kind: Annotated[str, typer.Option(help="kind of an image source (see estimate)")
                    ] = "equirect",
    lights: Annotated[int, typer.Option(help="most lights to extract from an image source")
                      ] = 16,
    ball_center: Annotated[str | None, typer.Option(help="mirror ball centre 'cx,cy'")] = None,
    ball_radius: Annotated[float | None, typer.Option(help="mirror ball radius (px)")] = None,
    ball_look: Annotated[str | None, typer.Option(help="mirror ball camera view 'x,y,z'")
                         ] = None,
    ball_up: Annotated[str | None, typer.Option(help="mirror ball camera up 'x,y,z'")] = None,
    fisheye_calib: Annotated[Path | None, typer.Option(help="fisheye calibration")] = None,
    fov: Annotated[float | None, typer.Option(
        help="fisheye field of view (deg); default: the calibration's, else 180")] = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an existing picture arlight did not write (never an "
        "input)")] = False,
    force: Force = False,
) -> None:
    """Picture a light estimate: map with the lights, SH reconstruction, irradiance."""
    from arlight.light.estimate import LightEstimate, hdr_map_path, read_json
    from arlight.output_guard import record_written, referenced_files

    _check_count(lights, "--lights", 0, MAX_LIGHTS)
    if source.is_dir():
        raise InputError("is a folder, expected a light JSON or an image", file=str(source))
    is_json = source.suffix.lower() == ".json"
    # the light JSON's HDR map is an input too
    inputs = (referenced_files(source) if is_json else [source]) + (
        [fisheye_calib] if fisheye_calib else [])
    _check_output(output, inputs)
    if is_json:
        d = read_json(source)
        if isinstance(d.get("hdr_map"), dict) and "file" in d["hdr_map"]:
            try:
                check_image_bounds([hdr_map_path(d, source.parent)], force)
            except InputError as exc:
                raise InputError(exc.message, file=str(source), field=exc.field) from exc
        est = LightEstimate.load(source)
    else:
        if source.is_file():
            check_image_bounds([source], force)
        env = load_environment(source, kind, None, ball_center, ball_radius,
                               fisheye_calib, fov, ball_look=ball_look, ball_up=ball_up)
        for w in env.warnings:
            typer.echo(f"warning: {w}", err=True)
        _check_output(output, inputs, overwrite=overwrite)
        est = LightEstimate.from_envmap(env.map, n_lights=lights,
                                        confidence=env.confidence, sh_map=env.sh_map)
    _check_output(output, inputs, overwrite=overwrite)
    render_picture(est, output, title=source.name)
    record_written([output])
    typer.echo(f"wrote {output}")

