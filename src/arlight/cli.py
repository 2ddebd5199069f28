"""The ``arlight`` command line.

    arlight demo                       render the bundled demo scene
    arlight render SCENE -m reference  run a method on an AR scene, write layers
    arlight synth WORLD                synthesise a camera frame + ground truth
    arlight validate SCENE             check a scene file and summarise it
    arlight methods [NAME]             list methods, or one's options and capabilities
    arlight light ...                  light estimation (SH, env maps, probes, fisheye)
    arlight eval ...                   evaluation harness (scenes × methods → report)

Errors in the input print one line naming the file and field and exit with status 2.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from arlight.errors import ArlightError
from arlight.evaluate import cli as eval_cli
from arlight.light import cli as light_cli

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="arlight: photorealistic AR — insert virtual objects into real frames "
                       "with the real light on them (differential rendering on Mitsuba 3).")
console = Console(stderr=True)

Spp = Annotated[int, typer.Option("--spp", help="samples per pixel (stratified when a "
                                                "perfect square)", min=1)]
Seed = Annotated[int, typer.Option("--seed", help="random seed; equal seeds give identical "
                                                  "images")]
MaxDepth = Annotated[int, typer.Option("--max-depth", help="longest path in vertices "
                                       "(Mitsuba convention: 2 = direct light only, "
                                       "-1 = unlimited)")]


@app.command()
def render(
    scene: Annotated[Path, typer.Argument(help="AR scene file (.toml or .json)")],
    method: Annotated[str, typer.Option("--method", "-m", help="registered method name "
                                        "(see `arlight methods`)")] = "reference",
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")] = Path("out"),
    spp: Spp = 64,
    seed: Seed = 0,
    max_depth: MaxDepth = 8,
    option: Annotated[list[str] | None, typer.Option("--option", help="method option "
                      "key=value, e.g. reproject=false (repeatable; `arlight methods NAME` "
                      "lists them)")] = None,
    progressive: Annotated[bool, typer.Option(help="progressive refinement: accumulate "
                           "composited frames (Kán Eq. 4.12) until --time or --frames")] = False,
    time_budget: Annotated[float, typer.Option("--time", help="progressive time budget, "
                           "seconds")] = 30.0,
    frames: Annotated[int, typer.Option(help="progressive frame budget (0 = time only)")] = 0,
    ground_truth: Annotated[Path | None, typer.Option(help="ground-truth EXR; progressive "
                            "mode reports the error as it falls")] = None,
) -> None:
    """Run a method on an AR scene and write its layers (EXR) and composite (PNG)."""
    from arlight.methods import RenderSettings, get_method
    from arlight.methods.spec import parse_option_pairs
    from arlight.output import write_layers
    from arlight.scene.load import load_scene

    settings = RenderSettings(spp=spp, seed=seed, max_depth=max_depth, progress=True,
                              options=parse_option_pairs(option or []))
    fn = get_method(method)
    fn.spec.parse_options(settings.options)  # a bad option fails before the scene loads
    sc = load_scene(scene)
    if progressive:
        from arlight.progressive import run_cli

        run_cli(sc, method, settings, out, time_budget, frames, ground_truth, console)
        return
    layers = fn(sc, settings)
    paths = write_layers(layers, sc, out)
    s = layers.stats
    rays = f", {s['rays_per_sample']:.2f} rays/sample" if "rays_per_sample" in s else ""
    console.print(f"[green]{method}[/]: {s.get('seconds', 0):.2f} s, "
                  f"{s.get('samples_per_second', 0) / 1e6:.2f} Msamples/s{rays}")
    from arlight.timing import format_stages

    if stages := format_stages(s):
        console.print(f"stages: {stages}")
    console.print(f"composite: {paths['composite_png']}  (layers: {out}/*.exr)")


@app.command()
def synth(
    world: Annotated[Path, typer.Argument(help="world scene file: real shapes = the real "
                                          "world, virtual shapes = objects to insert")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")] = Path("synth"),
    spp: Spp = 256,
    seed: Seed = 1,
    max_depth: MaxDepth = 8,
    no_cache: Annotated[bool, typer.Option(help="render even if cached")] = False,
    batches: Annotated[int, typer.Option(help="independent batches the per-pixel standard "
                                         "errors are estimated from (>= 2, at most --spp)",
                                         min=2)] = 64,
) -> None:
    """Synthesise a camera frame (world without virtual objects) and its ground truth with
    Mitsuba's own path tracer (independent of every method it grades)."""
    from arlight.io.images import write_exr, write_png
    from arlight.scene.load import load_scene
    from arlight.synthetic import synthesize

    w = load_scene(world)
    photo = synthesize(w, spp=spp, seed=seed, max_depth=max_depth, use_cache=not no_cache,
                       progress=True, batches=batches)
    t = w.camera.transfer
    write_exr(out / "frame.exr", photo.frame)
    write_png(out / "frame.png", t.to_display(photo.frame))
    write_exr(out / "frame_stderr.exr", photo.frame_stderr)
    write_exr(out / "ground_truth.exr", photo.ground_truth)
    write_png(out / "ground_truth.png", t.to_display(photo.ground_truth))
    write_exr(out / "ground_truth_stderr.exr", photo.ground_truth_stderr)
    write_exr(out / "mask.exr", photo.mask)
    console.print(f"frame and ground truth written to {out}/ (cache key {photo.key})")


@app.command()
def validate(scene: Annotated[Path, typer.Argument(help="AR scene file")]) -> None:
    """Check a scene file; print a summary or the first error (file and field)."""
    from arlight.scene.load import load_scene

    sc = load_scene(scene)
    cam = sc.camera
    typer.echo(f"{scene}: ok — camera {cam.width}×{cam.height} fx={cam.fx:.1f}, "
               f"{len(sc.real_shapes)} real and {len(sc.virtual_shapes)} virtual shapes, "
               f"{len(sc.lights)} lights, frame: {'yes' if sc.frame is not None else 'no'}")


@app.command()
def methods(
    name: Annotated[str | None, typer.Argument(help="a method: print its description, "
                                               "capabilities and options")] = None,
) -> None:
    """List the registered rendering methods, or describe one."""
    from rich.console import Console as RichConsole
    from rich.table import Table

    from arlight.methods import get_method, load_errors
    from arlight.methods import methods as registered

    if name is None:
        for n, m in registered().items():
            typer.echo(f"{n:12s} {m.spec.description}")
        for n, why in load_errors().items():
            typer.echo(f"{n:12s} (failed to load: {why})")
        return
    spec = get_method(name).spec
    typer.echo(f"{spec.name}: {spec.description}\n")
    typer.echo("capabilities:")
    for key, value in spec.capabilities.summary().items():
        typer.echo(f"  {key:12s} {value}")
    typer.echo("")
    if not spec.options:
        typer.echo("options: none")
        return
    table = Table("option", "type", "default", "unit", "meaning", title="options "
                  "(--option key=value)", title_justify="left")
    for row in spec.options_rows():
        table.add_row(*row)
    RichConsole(width=max(100, RichConsole().width)).print(table)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")] = Path("out/demo"),
    spp: Spp = 36,
    method: Annotated[str, typer.Option("--method", "-m", help="method to run")] = "reference",
) -> None:
    """Render the bundled demo scene (a virtual bunny on a real table) and print the paths."""
    from arlight.demo import run_demo

    run_demo(out, spp=spp, method=method, console=console)


# command groups that live in their own packages
app.add_typer(light_cli.app, name="light", help="light estimation: SH, environment maps, "
              "probes, fisheye cameras, light extraction")
app.command("eval")(eval_cli.eval_command)


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning input errors into one-line messages and exit 2."""
    try:
        app(args=argv, standalone_mode=False)
    except ArlightError as exc:
        console.print(f"[red]error:[/] {exc}")
        return 2
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        console.print("aborted")
        return 130
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            return exc.exit_code
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
