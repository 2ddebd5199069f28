"""``arlight eval``: run methods × suite scenes and write a comparison report.

    arlight eval --quick                                   every method on every scene
    arlight eval -m reference,onepass -s bunny-box --full  papers' resolutions
    arlight eval --cache-only                              fail cells whose ground truth
                                                           is not cached yet
    arlight eval --option onepass.reproject=false          an option of one method
    arlight eval --option reproject=false                  ... of every method declaring it

Mounted by :mod:`arlight.cli` as ``app.command("eval")(eval_command)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.errors import InputError


def _names(text: str | None, field: str) -> list[str] | None:
    """Comma-separated names (None or 'all' = every available one)."""
    if text is None or text.strip().lower() == "all":
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InputError(f"expected comma-separated names, got {text!r}", field=field)
    return list(dict.fromkeys(names))


def _ints(text: str, field: str) -> list[int]:
    try:
        vals = [int(x) for x in text.split(",") if x.strip()]
    except ValueError as exc:
        raise InputError(f"expected comma-separated integers, got {text!r}",
                         field=field) from exc
    return vals


def eval_command(
    methods: Annotated[str | None, typer.Option("--methods", "-m", help="comma-separated "
                       "registered methods (default: all, see `arlight methods`)")] = None,
    scenes: Annotated[str | None, typer.Option("--scenes", "-s", help="comma-separated suite "
                      "scenes (default: all)")] = None,
    quick: Annotated[bool, typer.Option("--quick/--full", help="CI resolution (80 px wide) "
                     "or the papers' resolutions (640×480, 960×540)")] = True,
    out: Annotated[Path, typer.Option("--out", "-o", help="report folder")] = Path(
        "eval-report"),
    spp: Annotated[int, typer.Option("--spp", help="samples per pixel for the methods")] = 16,
    gt_spp: Annotated[int, typer.Option("--gt-spp", help="samples per pixel of the frame "
                      "and ground truth")] = 256,
    repeats: Annotated[int, typer.Option("--repeats", help="timed runs per cell after one "
                       "warm-up (median reported)")] = 3,
    sweep: Annotated[str, typer.Option("--sweep", help="spp values for the error-vs-spp/"
                     "time plots, comma-separated ('' = none)")] = "1,4,16,64",
    seed: Annotated[int, typer.Option("--seed", help="method seed")] = 0,
    max_depth: Annotated[int, typer.Option("--max-depth", help="path depth (Mitsuba "
                         "convention)")] = 8,
    no_cache: Annotated[bool, typer.Option("--no-cache", help="render the ground truth even "
                        "if cached, and do not cache it")] = False,
    cache_only: Annotated[bool, typer.Option("--cache-only", help="use only cached ground "
                          "truth; scenes without one are reported as errors")] = False,
    list_only: Annotated[bool, typer.Option("--list", help="list scenes and methods, then "
                         "exit")] = False,
    option: Annotated[list[str] | None, typer.Option("--option", help="method option "
                      "METHOD.KEY=VALUE for one method, or KEY=VALUE for every method that "
                      "has it (repeatable; see `arlight methods NAME`)")] = None,
) -> None:
    """Evaluate methods on the scene suite against path-traced ground truth; write a report
    (Markdown, HTML, JSON, CSV, image grids, plots)."""
    from rich.console import Console

    from arlight.evaluate.harness import EvalConfig, run_evaluation
    from arlight.evaluate.report import write_report
    from arlight.evaluate.suite import get_scene, list_scenes
    from arlight.methods import available_methods
    from arlight.methods.spec import parse_option_pairs

    console = Console(stderr=True)
    if list_only:
        for name in list_scenes():
            s = get_scene(name)
            typer.echo(f"scene  {name:20s} {s.description}")
        for name, doc in available_methods().items():
            typer.echo(f"method {name:20s} {doc}")
        return
    cfg = EvalConfig(methods=_names(methods, "methods") or list(available_methods()),
                     scenes=_names(scenes, "scenes") or list_scenes(), quick=quick, spp=spp,
                     gt_spp=gt_spp, repeats=repeats, seed=seed, max_depth=max_depth,
                     use_cache=not no_cache, cache_only=cache_only,
                     sweep_spp=_ints(sweep, "sweep"),
                     options=parse_option_pairs(option or [], "[method.]key=value"))
    results = run_evaluation(cfg, log=console.print)
    paths = write_report(results, out)
    failed = sum(bool(c.error) for c in results.cells)
    skipped = sum(bool(c.skipped) for c in results.cells)
    console.print(f"report: {paths['markdown']} and {paths['html']} "
                  f"({len(results.cells)} cells, {failed} failed, {skipped} skipped, "
                  f"{results.seconds_total:.1f} s)")
