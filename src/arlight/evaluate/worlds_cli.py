"""``arlight worlds``: generated worlds for held-out evaluation (issue #30).

    arlight worlds make --seed 1000003 -o world-1000003     scene files + renders
    arlight worlds make --seed 7 -o w7 --width 160 --spp 64  a training world, small
    arlight worlds make --seed 7 -o w7 --no-render           scene files only
    arlight worlds list --worlds heldout:24                  what each world holds

Mounted by :mod:`arlight.cli` as the ``worlds`` command group.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_SPP
from arlight.cli_options import Force

app = typer.Typer(no_args_is_help=True, add_completion=False, help=(
    "generated worlds: seeds below 1 000 000 are training worlds (tune here), seeds from "
    "1 000 000 on are held-out worlds (report here); see docs/evaluation.md#generated-worlds"))

WORLD_FILES = ("world.toml", "proxy.toml", "assets", "frame.exr", "frame.png",
               "frame_stderr.exr", "ground_truth.exr", "ground_truth.png",
               "ground_truth_stderr.exr", "mask.exr", "depth.exr")
MAX_WIDTH = 4096


@app.command("make")
def make(
    seed: Annotated[int, typer.Option("--seed", help="world seed: 0 to 999 999 training, "
                                      "1 000 000 and above held out", min=0,
                                      max=2**31 - 1)],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder (a new one, or "
                                      "one this command wrote)")],
    width: Annotated[int, typer.Option("--width", help="image width in pixels (the height "
                                       "keeps 4:3)", min=8, max=MAX_WIDTH)] = 640,
    spp: Annotated[int, typer.Option("--spp", help="samples per pixel of the frame and "
                                     "ground truth", min=2, max=MAX_SPP)] = 256,
    max_depth: Annotated[int, typer.Option("--max-depth", help="longest path in vertices "
                                           "(Mitsuba convention)", min=-1, max=1024)] = 8,
    render: Annotated[bool, typer.Option("--render/--no-render", help="also render the "
                                         "frame, ground truth, mask and depth")] = True,
    no_cache: Annotated[bool, typer.Option("--no-cache", help="render even if cached")] =
        False,
    force: Force = False,
) -> None:
    """Write a generated world: world.toml (the real world with the virtual objects),
    proxy.toml (the coarser reconstruction a method gets, its frame and depth attached),
    the assets they use and, with --render, the synthetic frame, ground truth, standard
    errors, mask and depth (Mitsuba's path tracer, cached)."""
    from rich.console import Console

    from arlight.bounds import check_estimate, estimate
    from arlight.evaluate.worlds import generate
    from arlight.io.images import write_exr, write_png
    from arlight.staged_output import StagedOutput, check_output_dir
    from arlight.synthetic import sensor_depth, synthesize

    world = generate(seed)
    height = max(1, round(width * 3 / 4))
    if render:
        check_estimate(estimate(width, height, spp, paths=2, layers=8),
                       f"synthesising {world.name} at {width}×{height}, {spp} spp", force)
    check_output_dir(out, WORLD_FILES, 16 * width * height * 8 + (8 << 20))
    console = Console(stderr=True)
    console.print(f"{world.name} ({world.split}): {world.describe()}")
    photo = depth = None
    if render:
        ws, _ = world.scenes(width)
        photo = synthesize(ws, spp=spp, seed=1, max_depth=max_depth, use_cache=not no_cache,
                           progress=True)
        depth = sensor_depth(ws)
    with StagedOutput(out, "worlds make", WORLD_FILES) as tmp:
        frame = None
        if photo is not None:
            t = ws.camera.transfer
            write_exr(tmp / "frame.exr", photo.frame)
            write_png(tmp / "frame.png", t.to_display(photo.frame))
            write_exr(tmp / "frame_stderr.exr", photo.frame_stderr)
            write_exr(tmp / "ground_truth.exr", photo.ground_truth)
            write_png(tmp / "ground_truth.png", t.to_display(photo.ground_truth))
            write_exr(tmp / "ground_truth_stderr.exr", photo.ground_truth_stderr)
            write_exr(tmp / "mask.exr", photo.mask)
            write_exr(tmp / "depth.exr", depth)
            frame = {"image": "frame.exr", "depth": "depth.exr"}
        world.write(tmp, width=width, frame=frame)
    console.print(f"written to {out}/ (world.toml, proxy.toml"
                  f"{', frame, ground truth, mask, depth' if render else ''})")


@app.command("list")
def list_worlds(
    worlds: Annotated[str, typer.Option("--worlds", "-w", help="SPLIT:N (training:8, "
                                        "heldout:24), SPLIT:N+START, or comma-separated "
                                        "seeds")] = "heldout:24",
) -> None:
    """Print what each generated world holds (class, scale, lights, materials)."""
    from arlight.evaluate.worlds import generate, parse_worlds

    for seed in parse_worlds(worlds):
        w = generate(seed)
        typer.echo(f"{seed:>9d} {w.split:8s} {w.describe()}")
