"""The ``arlight`` command line.

    arlight demo                       render the bundled demo scene
    arlight render SCENE -m reference  run a method on an AR scene, write layers
    arlight synth WORLD                synthesise a camera frame + ground truth
    arlight validate SCENE             check a scene file and summarise it
    arlight methods [NAME]             list methods, or one's options and capabilities
    arlight light ...                  light estimation (SH, env maps, probes, fisheye)
    arlight eval ...                   evaluation harness (scenes × methods → report)
    arlight worlds make --seed S -o D  a generated world (training or held-out) + renders
    arlight insert PHOTO ...           insert a virtual object into a photo with a marker
    arlight studio SCENE               live AR composite in the browser (drag, switch methods)
    arlight sequence SCENE ...         render an AR video (resumable, optionally on Ray)
    arlight live --example             live AR from a camera or video, shown in the studio

Errors in the input print one line naming the file and field and exit with status 2.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_FRAMES, MAX_SECONDS_BUDGET, MAX_SEED, MAX_SPP
from arlight.cli_options import Force
from arlight.errors import ArlightError
from arlight.evaluate import cli as eval_cli
from arlight.evaluate import worlds_cli
from arlight.importers.cli import import_mitsuba_command
from arlight.insert.cli import insert_command
from arlight.light import cli as light_cli
from arlight.lightserver.cli import client_command, serve_light_command
from arlight.live.cli import live_command
from arlight.nearfield.cli import atlas as atlas_command
from arlight.probeless.cli import probeless as probeless_command
from arlight.sequence.cli import sequence_command
from arlight.studio.cli import studio_command

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="arlight: photorealistic AR — insert virtual objects into real frames "
                       "with the real light on them (differential rendering on Mitsuba 3).")
_CONSOLE = []


def _console():
    """The rich console on stderr, made on first use (rich costs ~70 ms to import, paid
    only by the commands that print progress)."""
    if not _CONSOLE:
        from rich.console import Console

        _CONSOLE.append(Console(stderr=True))
    return _CONSOLE[0]



@app.callback()
def _global_options(
    debug: Annotated[bool, typer.Option("--debug", help="print the traceback of an error "
                                        "(also ARLIGHT_DEBUG=1)")] = False,
) -> None:
    """Global options (read by :func:`main` before the command runs)."""

Spp = Annotated[int, typer.Option("--spp", help="samples per pixel (stratified when a "
                                                "perfect square)", min=1, max=MAX_SPP)]
Seed = Annotated[int, typer.Option("--seed", help="random seed (0 to 2^32-1); equal seeds "
                                   "give identical images", min=0, max=MAX_SEED)]

SYNTH_FILES = ("frame.exr", "frame.png", "frame_stderr.exr", "ground_truth.exr",
               "ground_truth.png", "ground_truth_stderr.exr", "mask.exr")
MaxDepth = Annotated[int, typer.Option("--max-depth", help="longest path in vertices "
                                       "(Mitsuba convention: 2 = direct light only, "
                                       "-1 = unlimited)")]


def _check_before_work(cam, spp: int, what: str, force: bool, out: Path,
                       known: tuple[str, ...], inputs: tuple[Path, ...] = (), layers: int = 12,
                       renders: float = 1.0, snapshots: int = 1) -> None:
    """The checks every rendering command makes before any work: the cost estimate of a
    differential render of the camera ``cam`` at ``spp`` (refused beyond the limits unless
    ``force``), then the output folder ``out`` (room for ``snapshots`` sets of ``layers``
    images; see :func:`arlight.staged_output.check_output_dir`)."""
    from arlight.bounds import check_estimate, estimate
    from arlight.staged_output import check_output_dir

    est = estimate(cam.width, cam.height, spp, paths=2, layers=layers, renders=renders)
    check_estimate(est, what, force)
    check_output_dir(out, known, int(est.output_bytes * snapshots), inputs)


@app.command()
def render(
    scene: Annotated[Path, typer.Argument(help="AR scene file (.toml or .json)")],
    method: Annotated[str | None, typer.Option("--method", "-m", help="registered method "
                      "name (see `arlight methods`; default: the scene's render table, "
                      "else reference)")] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")] = Path("out"),
    frame: Annotated[Path | None, typer.Option("--frame", help="background frame image "
                     "(LDR or HDR, the camera's size) replacing the scene's frame "
                     "image")] = None,
    spp: Spp = None,  # type: ignore[assignment]  # None: the scene's [render] value, else 64
    seed: Seed = None,  # type: ignore[assignment]  # else 0
    max_depth: MaxDepth = None,  # type: ignore[assignment]  # else 8
    option: Annotated[list[str] | None, typer.Option("--option", help="method option "
                      "key=value, e.g. reproject=false (repeatable; `arlight methods NAME` "
                      "lists them)")] = None,
    progressive: Annotated[bool, typer.Option(help="progressive refinement: accumulate "
                           "composited frames (Kán Eq. 4.12) until --time or --frames")] = False,
    time_budget: Annotated[float, typer.Option("--time", help="progressive time budget, "
                           "seconds (> 0)", min=0,
                           max=MAX_SECONDS_BUDGET)] = 30.0,
    frames: Annotated[int, typer.Option(help="progressive frame budget (0 = time only)",
                                        min=0, max=MAX_FRAMES)] = 0,
    ground_truth: Annotated[Path | None, typer.Option(help="ground-truth EXR; progressive "
                            "mode reports the error as it falls")] = None,
    force: Force = False,
) -> None:
    """Run a method on an AR scene and write its layers (EXR) and composite (PNG).

    --method, --spp, --seed, --max-depth and --option override the scene's render table.
    """
    import numpy as np

    from arlight.bounds import check_range
    from arlight.layer_files import LAYER_FILES, write_layers
    from arlight.methods import RenderSettings, get_method
    from arlight.methods.spec import parse_option_pairs
    from arlight.scene.load import load_scene, render_settings_for

    given = render_settings_for(scene, method, spp, max_depth, seed,
                                parse_option_pairs(option or []))
    method, spp, seed, max_depth = (given[k] for k in ("method", "spp", "seed", "max_depth"))
    settings = RenderSettings(spp=spp, seed=seed, max_depth=max_depth, progress=True,
                              options=given["options"])
    check_range(time_budget, "--time", 0, MAX_SECONDS_BUDGET, lo_open=True)
    # the scene first: loading it needs no renderer, so a bad scene is refused before the
    # methods (and Mitsuba with them, ~1 s) are imported
    sc = load_scene(scene, frame=frame)
    fn = get_method(method)
    fn.spec.parse_options(settings.options)
    if progressive:
        from arlight.progressive import progressive_method

        progressive_method(method)
    cam = sc.camera
    inputs = (scene,) if ground_truth is None else (scene, ground_truth)
    # progressive mode renders `frames` frames (a time-only budget is bounded by --time)
    _check_before_work(cam, spp, f"rendering {cam.width}×{cam.height} at {spp} spp", force,
                       out, LAYER_FILES, inputs,
                       renders=frames if progressive and frames else 1,
                       snapshots=(int(np.log2(frames)) + 2) if progressive and frames else 1)
    if progressive:
        from arlight.progressive import run_cli

        run_cli(sc, method, settings, out, time_budget, frames, ground_truth, _console())
        return
    layers = fn(sc, settings)
    paths = write_layers(layers, sc, out)
    s = layers.stats
    rays = f", {s['rays_per_sample']:.2f} rays/sample" if "rays_per_sample" in s else ""
    _console().print(f"[green]{method}[/]: {s.get('seconds', 0):.2f} s, "
                  f"{s.get('samples_per_second', 0) / 1e6:.2f} Msamples/s{rays}")
    from arlight.timing import format_stages

    if stages := format_stages(s):
        _console().print(f"stages: {stages}")
    _console().print(f"composite: {paths['composite_png']}  (layers: {out}/*.exr)")


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
                                         min=2, max=MAX_SPP)] = 64,
    sampler: Annotated[str, typer.Option(help="Mitsuba sampler of every batch: multijitter "
                                         "(stratified, lowest error), ldsampler, orthogonal "
                                         "or independent")] = "multijitter",
    force: Force = False,
) -> None:
    """Synthesise a camera frame (world without virtual objects) and its ground truth with
    Mitsuba's own path tracer (independent of every method it grades)."""
    from arlight.io.images import write_exr, write_png
    from arlight.scene.load import load_scene
    from arlight.staged_output import StagedOutput
    from arlight.synthetic import batch_plan, synthesize

    batch_plan(spp, batches, sampler)  # spp/batches/sampler errors before the scene loads
    w = load_scene(world)
    cam = w.camera
    _check_before_work(cam, spp, f"synthesising {cam.width}×{cam.height} at {spp} spp", force,
                       out, SYNTH_FILES, (world,), layers=7)
    photo = synthesize(w, spp=spp, seed=seed, max_depth=max_depth, use_cache=not no_cache,
                       progress=True, batches=batches, sampler=sampler)
    t = w.camera.transfer
    with StagedOutput(out, "synth", SYNTH_FILES) as tmp:
        write_exr(tmp / "frame.exr", photo.frame)
        write_png(tmp / "frame.png", t.to_display(photo.frame))
        write_exr(tmp / "frame_stderr.exr", photo.frame_stderr)
        write_exr(tmp / "ground_truth.exr", photo.ground_truth)
        write_png(tmp / "ground_truth.png", t.to_display(photo.ground_truth))
        write_exr(tmp / "ground_truth_stderr.exr", photo.ground_truth_stderr)
        write_exr(tmp / "mask.exr", photo.mask)
    _console().print(f"frame and ground truth written to {out}/ (cache key {photo.key})")


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
    force: Force = False,
) -> None:
    """Render the bundled demo scene (a virtual bunny on a real table) and print the paths."""
    from arlight.demo import demo_scene_path, run_demo
    from arlight.layer_files import LAYER_FILES
    from arlight.methods import get_method
    from arlight.scene.load import load_scene

    get_method(method)
    cam = load_scene(demo_scene_path()).camera
    _check_before_work(cam, spp, f"rendering the demo at {spp} spp", force, out, LAYER_FILES)

    run_demo(out, spp=spp, method=method, console=_console())


# command groups that live in their own packages; the engines of `light probeless` (Gruber
# et al. 2014) and `light atlas` (Rohmer et al. 2015, near-field server update) keep their
# commands in their own packages and are mounted on the `light` group here
light_cli.app.command("probeless")(probeless_command)
light_cli.app.command("atlas")(atlas_command)
app.add_typer(light_cli.app, name="light", help="light estimation: SH, environment maps, "
              "probes, fisheye cameras, light extraction")
app.command("eval")(eval_cli.eval_command)
app.add_typer(worlds_cli.app, name="worlds")
app.command("import-mitsuba")(import_mitsuba_command)
app.command("insert")(insert_command)
app.command("serve-light")(serve_light_command)
app.command("client")(client_command)
app.command("studio")(studio_command)
app.command("sequence")(sequence_command)
app.command("live")(live_command)


def _usage_error_types() -> tuple[type[BaseException], ...]:
    """Exception classes of the command-line parser's usage errors.

    Typer >= 0.20 vendors Click as ``typer._click`` (its exceptions derive from
    ``typer.exceptions.TyperException``); older Typer versions use the ``click`` package.
    """
    types: list[type[BaseException]] = []
    try:
        from typer.exceptions import TyperException

        types.append(TyperException)
    except ImportError:
        pass
    try:
        from click.exceptions import ClickException

        types.append(ClickException)
    except ImportError:
        pass
    return tuple(types)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _error(message: str) -> None:
    """One line on stderr (never wrapped, whatever the terminal width)."""
    print(f"error: {_one_line(message)}", file=sys.stderr, flush=True)


def _usage_message(exc: BaseException) -> str:
    ctx = getattr(exc, "ctx", None)
    command = getattr(ctx, "command_path", None) or "arlight"
    fmt = getattr(exc, "format_message", None)
    text = fmt() if callable(fmt) else str(exc)
    return f"{command}: {_one_line(text)} (see '{command} --help')"


def _debug_requested(argv: list[str]) -> bool:
    return os.environ.get("ARLIGHT_DEBUG", "") not in ("", "0") or "--debug" in argv


class _Interrupted(KeyboardInterrupt):
    """SIGINT/SIGTERM turned into an exception that unwinds (and cleans) staged outputs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


_SIGNALS: list[int] = []
"""Signals received by :func:`main` (Typer turns KeyboardInterrupt into exit code 130)."""


def _on_signal(signum: int, _frame: object) -> None:
    from arlight import interrupts

    if interrupts.deferring():  # inside a native call: raised when it returns
        interrupts.defer(signum)
        return
    _SIGNALS.append(signum)
    raise _Interrupted(signum)


def _interrupted(signum: int, committed: int) -> int:
    """The one line after SIGINT/SIGTERM; returns 128 + the signal number."""
    import signal

    from arlight import staged_output

    done = staged_output.COMMITTED[committed:]
    name = "SIGTERM" if signum == signal.SIGTERM else "interrupt (SIGINT)"
    if done:
        _error(f"{name}: stopped after writing {', '.join(map(str, done))}")
    else:
        _error(f"{name}: stopped; the output was not written (an existing output is left "
               "as it was)")
    return 128 + int(signum)


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI with one error path for every command.

    Exit status 0 on success; 2 for usage errors and bad input (:class:`ArlightError`),
    with one line on stderr naming the file and field; 1 for internal errors (one line;
    the traceback with ``--debug`` or ``ARLIGHT_DEBUG=1``); 130 after SIGINT (143 after
    SIGTERM) with a line saying that no output was written. Bare ``arlight`` (or a bare
    command group) prints the help and exits 2.
    """
    import signal
    import threading
    import traceback

    from arlight import staged_output

    args = list(sys.argv[1:] if argv is None else argv)
    debug = _debug_requested(args)
    usage_types = _usage_error_types()
    previous: dict[int, object] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, _on_signal)
    committed = len(staged_output.COMMITTED)
    _SIGNALS.clear()
    try:
        from arlight.cli_progress import terminal_bars

        with terminal_bars():  # engines' progress tasks show as bars on stderr
            rv = app(args=args, standalone_mode=False, prog_name="arlight")
        if _SIGNALS:
            return _interrupted(_SIGNALS[0], committed)
        return rv if isinstance(rv, int) else 0
    except KeyboardInterrupt as exc:
        return _interrupted(getattr(exc, "signum", signal.SIGINT), committed)
    except ArlightError as exc:
        if debug:
            traceback.print_exc()
        _error(str(exc))
        return 2
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        _error("aborted; the output was not written")
        return 130
    except usage_types as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":
            print(exc.format_message(), file=sys.stdout)  # bare command: its help
            return 2
        if debug:
            traceback.print_exc()
        _error(_usage_message(exc))
        return 2  # every parser error is a usage error or a file it cannot open
    except Exception as exc:  # noqa: BLE001 - the one place unexpected errors end up
        if debug:
            traceback.print_exc()
        where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
        at = f" at {Path(where.filename).name}:{where.lineno}" if where else ""
        _error(f"internal error ({type(exc).__name__}{at}): {exc} — rerun with --debug "
               "for the traceback")
        return 1
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]


if __name__ == "__main__":
    sys.exit(main())
