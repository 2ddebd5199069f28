"""``arlight light``: estimate lights from a probe / map / fisheye image, and picture them.

Examples::

    python -m arlight.light.cli estimate grace.hdr --kind equirect --lights 16 -o light.json
    python -m arlight.light.cli estimate ball.exr --kind ball --ball-center 512,500 \\
        --ball-radius 480 -o light.json
    python -m arlight.light.cli estimate sky.png --kind fisheye --fov 185 -o light.json
    python -m arlight.light.cli show light.json -o light.png

Outputs are written to a temporary file and renamed, so a failed run leaves nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from arlight.bounds import MAX_LIGHTS, MAX_SH_HEIGHT, MAX_SH_ORDER
from arlight.io.images import atomic_write, read_linear
from arlight.light.estimate import LAYOUTS, LightEstimate
from arlight.light.extract import ExtractedLight
from arlight.sphere import envmap as E
from arlight.sphere import sh as SH
from arlight.sphere.fisheye import FisheyeCamera

KINDS = ("equirect", "probe", "ball", "fisheye")

app = typer.Typer(
    help="Light estimation: SH, environment maps, probes, fisheye images, light extraction.",
    no_args_is_help=True,
    add_completion=False,
)


class CliError(Exception):
    """A user error: printed without a traceback, exit status 2."""


def _fail(message: str) -> None:
    """One line on stderr, exit status 2 (also when the sub-app runs on its own)."""
    typer.echo(f"error: {' '.join(str(message).split())}", err=True)
    raise typer.Exit(code=2)


def _check_number(value: float | None, option: str, lo: float, hi: float,
                  lo_open: bool = True) -> None:
    if value is None:
        return
    if not np.isfinite(value) or (value <= lo if lo_open else value < lo) or value > hi:
        raise CliError(f"{option}: expected a finite number in {'(' if lo_open else '['}"
                       f"{lo:g}, {hi:g}], got {value}")


def _check_output(output: Path, inputs: list[Path], option: str = "--output") -> None:
    """The output file: not an input, not a folder or dangling symlink, parent writable."""
    import os

    for inp in inputs:
        if inp is not None and (output.resolve() == inp.resolve()
                                or (output.exists() and inp.exists()
                                    and output.samefile(inp))):
            raise CliError(f"{option} {output}: would overwrite the input {inp}")
    if output.is_symlink() and not output.exists():
        raise CliError(f"{option} {output}: is a dangling symlink")
    if output.is_dir():
        raise CliError(f"{option} {output}: is a folder, expected a file name")
    parent = output.parent if str(output.parent) else Path(".")
    while not parent.exists() and parent.parent != parent:
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise CliError(f"{option} {output}: folder {parent} is not writable")


def _parse_center(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        cx, cy = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise CliError(f"--ball-center: expected 'cx,cy' in pixels, got {text!r}") from exc
    return cx, cy


def load_environment(image: Path, kind: str, height: int | None = None,
                     ball_center: str | None = None, ball_radius: float | None = None,
                     fisheye_calib: Path | None = None, fov: float = 180.0,
                     mirror_lower: bool = True
                     ) -> tuple[np.ndarray, float, np.ndarray | None]:
    """Read ``image`` of ``kind``: (equirect map of what was observed, observed sphere
    fraction, map for the SH remainder when it differs -- the mirrored fisheye capture)."""
    if kind not in KINDS:
        raise CliError(f"--kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    from arlight.io.images import is_hdr_path

    if kind in ("equirect", "probe") and not is_hdr_path(image):
        raise CliError(f"{image}: an {kind} environment map must be HDR (.exr/.hdr/.pfm); "
                       "an 8/16-bit picture holds display values clipped at white, not "
                       "radiance")
    _check_number(fov, "--fov", 0.0, 360.0)
    _check_number(ball_radius, "--ball-radius", 0.0, 1e6)
    img = read_linear(image)
    H, W = img.shape[:2]
    if np.any(img < 0):
        raise CliError(f"{image}: {int(np.count_nonzero(img < 0))} negative values; radiance "
                       "must be >= 0")
    if kind == "equirect":
        if W != 2 * H:
            raise CliError(f"{image}: an equirect map must be 2:1, got {W}x{H}")
        return E.to_equirect(img, "equirect", height=height), 1.0, None
    if kind == "probe":
        if W != H:
            raise CliError(f"{image}: an angular light probe must be square, got {W}x{H}")
        return E.to_equirect(img, "angular", height=height), 1.0, None
    if kind == "ball":
        center = _parse_center(ball_center)
        if center is None or ball_radius is None or ball_radius <= 0:
            raise CliError("--kind ball needs --ball-center cx,cy and --ball-radius (pixels)")
        cx, cy = center
        if not (np.isfinite(cx) and np.isfinite(cy)):
            raise CliError(f"--ball-center: expected finite pixel coordinates, got {center}")
        tol = 1.0
        if (cx - ball_radius < -tol or cy - ball_radius < -tol
                or cx + ball_radius > W + tol or cy + ball_radius > H + tol):
            raise CliError(f"--ball-center/--ball-radius: the ball (centre {cx:g},{cy:g}, "
                           f"radius {ball_radius:g} px) is not inside the {W}x{H} image "
                           f"{image}")
        m = E.to_equirect(img, "ball", height=height, center=center, radius=ball_radius)
        return m, 1.0, None
    if fisheye_calib is not None:
        try:
            cam = FisheyeCamera.load(fisheye_calib, fov_deg=fov)
        except ValueError as exc:
            raise CliError(f"--fisheye-calib: {exc}") from exc
        if cam.size != (W, H):
            raise CliError(f"{image}: image is {W}x{H} but {fisheye_calib} is for "
                           f"{cam.size[0]}x{cam.size[1]}")
    else:
        cam = FisheyeCamera.equidistant((W, H), fov_deg=fov)
    m = E.to_equirect(img, "fisheye", height=height, camera=cam)
    mirrored = E.mirror_lower_hemisphere(m) if mirror_lower else None
    observed = min(1.0, (1 - np.cos(np.radians(min(fov, 360.0) / 2))) / 2)
    return m, float(observed), mirrored


@app.command()
def estimate(
    image: Annotated[Path, typer.Argument(help="HDR (.hdr/.exr) or LDR image")],
    output: Annotated[Path, typer.Option("-o", "--output", help="light JSON to write")] = Path(
        "light.json"),
    kind: Annotated[str, typer.Option(help="equirect | probe (Debevec angular) | ball | "
                                           "fisheye")] = "equirect",
    lights: Annotated[int, typer.Option(help="number of extracted lights (0: SH only)")] = 16,
    sh_order: Annotated[int, typer.Option(help="SH order L ((L+1)^2 coefficients)")] = 2,
    method: Annotated[str, typer.Option(help="median_cut | variance")] = "median_cut",
    threshold: Annotated[float | None, typer.Option(
        help="highlight luminance threshold (default 4x the mean)")] = None,
    height: Annotated[int | None, typer.Option(help="equirect height to work at")] = None,
    ball_center: Annotated[str | None, typer.Option(help="mirror ball centre 'cx,cy' (px)")
                           ] = None,
    ball_radius: Annotated[float | None, typer.Option(help="mirror ball radius (px)")] = None,
    fisheye_calib: Annotated[Path | None, typer.Option(
        help="OpenCV fisheye calibration (.yml/.xml) or JSON (K, D, size)")] = None,
    fov: Annotated[float, typer.Option(help="fisheye field of view (deg)")] = 180.0,
    mirror_lower: Annotated[bool, typer.Option(
        help="fisheye: mirror the upper hemisphere into the lower (Kan)")] = True,
    layout: Annotated[str, typer.Option(help="arlight | arcore | arkit | webxr")] = "arlight",
) -> None:
    """Estimate a LightEstimate (main light, extra lights, SH remainder) from an image."""
    try:
        if layout not in LAYOUTS:
            raise CliError(f"--layout: expected one of {', '.join(LAYOUTS)}, got {layout!r}")
        if method not in ("median_cut", "variance"):
            raise CliError(f"--method: expected median_cut or variance, got {method!r}")
        if not 0 <= lights <= MAX_LIGHTS:
            raise CliError(f"--lights: expected 0 to {MAX_LIGHTS}, got {lights}")
        if not 0 <= sh_order <= MAX_SH_ORDER:
            raise CliError(f"--sh-order: expected 0 to {MAX_SH_ORDER}, got {sh_order}")
        if height is not None and not 2 <= height <= MAX_SH_HEIGHT:
            raise CliError(f"--height: expected 2 to {MAX_SH_HEIGHT} pixels, got {height}")
        _check_number(threshold, "--threshold", 0.0, 1e30)
        inputs = [image] + ([fisheye_calib] if fisheye_calib is not None else [])
        _check_output(output, inputs)
        env, observed, sh_map = load_environment(image, kind, height, ball_center,
                                                 ball_radius, fisheye_calib, fov, mirror_lower)
        est = LightEstimate.from_envmap(env, n_lights=lights, sh_order=sh_order,
                                        method=method, threshold=threshold,
                                        confidence=observed, sh_map=sh_map)
        est.save(output, layout=layout, protect=tuple(inputs))
    except (CliError, ValueError) as exc:
        _fail(str(exc))
    typer.echo(f"wrote {output}: main light toward {np.round(est.main_direction, 3).tolist()}, "
               f"{len(est.lights)} more lights, SH order {sh_order}")


def _tonemap(img: np.ndarray) -> np.ndarray:
    scale = np.percentile(img, 99.0) or 1.0
    return np.clip(img / scale, 0, 1) ** (1 / 2.2)


def _irradiance_sphere(est: LightEstimate, size: int = 160) -> np.ndarray:
    """A white Lambertian sphere seen from +Z (radiance E/pi), black outside."""
    xs = (np.arange(size) + 0.5) / size * 2 - 1
    X, Y = np.meshgrid(xs, -xs)
    r2 = X**2 + Y**2
    inside = r2 <= 1
    n = np.stack([X, Y, np.sqrt(np.clip(1 - r2, 0, None))], axis=-1)
    out = np.zeros((size, size, 3))
    out[inside] = est.irradiance(n[inside]) / np.pi
    return out


def render_picture(est: LightEstimate, path: Path, title: str = "") -> Path:
    """Three panels: map + lights, SH reconstruction, irradiance sphere (PNG, atomic)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = SH.order_of(est.sh.shape[0])
    recon = SH.sh_to_equirect(est.total_sh(max(order, 2)), 128)
    env = est.hdr_map if est.hdr_map is not None else recon
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.6),
                             gridspec_kw={"width_ratios": [2, 2, 1]})
    ax = axes[0]
    ax.imshow(_tonemap(env), extent=(0, 1, 1, 0), aspect="auto")
    all_lights = [ExtractedLight(est.main_direction, est.main_irradiance), *est.lights]
    powers = np.array([lt.irradiance @ SH.LUMINANCE for lt in all_lights])
    pmax = powers.max() if powers.size and powers.max() > 0 else 1.0
    for i, (lt, p) in reversed(list(enumerate(zip(all_lights, powers, strict=True)))):
        x, y = E.direction_to_equirect(lt.direction[None], 1, 1)[0]
        ax.scatter([x % 1], [y], s=30 + 300 * p / pmax, facecolors="none",
                   edgecolors="red" if i == 0 else "yellow", linewidths=1.5)
    ax.set_title(f"map + {len(all_lights)} lights (red: main)")
    ax.set_xlabel("u")
    ax.set_ylabel("v")
    axes[1].imshow(_tonemap(recon), extent=(0, 1, 1, 0), aspect="auto")
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
    lights: Annotated[int, typer.Option(help="lights to extract from an image source")] = 16,
    ball_center: Annotated[str | None, typer.Option(help="mirror ball centre 'cx,cy'")] = None,
    ball_radius: Annotated[float | None, typer.Option(help="mirror ball radius (px)")] = None,
    fisheye_calib: Annotated[Path | None, typer.Option(help="fisheye calibration")] = None,
    fov: Annotated[float, typer.Option(help="fisheye field of view (deg)")] = 180.0,
) -> None:
    """Picture a light estimate: map with the lights, SH reconstruction, irradiance."""
    try:
        if not 0 <= lights <= MAX_LIGHTS:
            raise CliError(f"--lights: expected 0 to {MAX_LIGHTS}, got {lights}")
        _check_output(output, [source] + ([fisheye_calib] if fisheye_calib else []))
        if source.suffix.lower() == ".json":
            est = LightEstimate.load(source)
        else:
            env, observed, sh_map = load_environment(source, kind, None, ball_center,
                                                     ball_radius, fisheye_calib, fov)
            est = LightEstimate.from_envmap(env, n_lights=lights, confidence=observed,
                                            sh_map=sh_map)
        render_picture(est, output, title=source.name)
    except (CliError, ValueError) as exc:
        _fail(str(exc))
    typer.echo(f"wrote {output}")


# Probeless estimation from RGB-D (Gruber et al. 2014, issue 16): its code lives in
# arlight.probeless.cli; only the subcommand is registered here.
from arlight.probeless.cli import probeless as _probeless  # noqa: E402

app.command("probeless")(_probeless)


if __name__ == "__main__":
    app()
