"""``arlight eval``: run methods × suite scenes and write a comparison report.

    arlight eval --quick                                   every method on every scene
    arlight eval -m reference,onepass -s bunny-box --full  papers' resolutions
    arlight eval --cache-only                              fail cells whose ground truth
                                                           is not cached yet
    arlight eval --option onepass.reproject=false          an option of one method
    arlight eval --option reproject=false                  ... of every method declaring it
    arlight eval -m onepass,onepass+denoise=oidn           a method and a variant of it
                                                           (its own column, same run)
    arlight eval --worlds heldout:24 --width 160           every method on 24 held-out
                                                           generated worlds: distributions
                                                           and the equal-time table

Mounted by :mod:`arlight.cli` as ``app.command("eval")(eval_command)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from arlight.bounds import MAX_REPEATS, MAX_SEED, MAX_SPP
from arlight.errors import InputError
from arlight.evaluate.distribution import LADDER_SPP


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
                       "registered methods (default: all, see `arlight methods`); "
                       "NAME+key=value[+key=value] is a variant with those options, e.g. "
                       "onepass+denoise=oidn")] = None,
    scenes: Annotated[str | None, typer.Option("--scenes", "-s", help="comma-separated suite "
                      "scenes (default: all)")] = None,
    quick: Annotated[bool, typer.Option("--quick/--full", help="CI resolution (80 px wide) "
                     "or the papers' resolutions (640×480, 960×540)")] = True,
    out: Annotated[Path, typer.Option("--out", "-o", help="report folder")] = Path(
        "eval-report"),
    spp: Annotated[int, typer.Option("--spp", help="samples per pixel for the methods",
                                     min=1, max=MAX_SPP)] = 16,
    gt_spp: Annotated[int, typer.Option("--gt-spp", help="samples per pixel of the frame "
                      "and ground truth", min=2, max=MAX_SPP)] = 256,
    repeats: Annotated[int, typer.Option("--repeats", help="timed runs per cell after one "
                       "warm-up (median reported)", min=1, max=MAX_REPEATS)] = 3,
    sweep: Annotated[str, typer.Option("--sweep", help="spp values for the error-vs-spp/"
                     "time plots, comma-separated ('' = none)")] = "1,4,16,64",
    seed: Annotated[int, typer.Option("--seed", help="method seed (0 to 2^32-1)", min=0,
                                      max=MAX_SEED)] = 0,
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
    force: Annotated[bool, typer.Option("--force", help="run even when the estimated time "
                     "or memory is beyond the limits (see docs/cli.md)")] = False,
    worlds: Annotated[str | None, typer.Option("--worlds", "-w", help="generated worlds: "
                      "heldout:N (report here), training:N (tune here), SPLIT:N+START, or "
                      "comma-separated seeds; without --scenes the suite is not run")] = None,
    width: Annotated[int | None, typer.Option("--width", help="image width of the generated "
                     "worlds in px (default 80 with --quick, 640 with --full; 4:3)", min=8,
                     max=4096)] = None,
    equal_time: Annotated[bool | None, typer.Option("--equal-time/--no-equal-time",
                          help="time onepass on a ladder of spp per scene and compare each "
                          "method with onepass at its own frame time (default: on with "
                          "--worlds)")] = None,
    ladder: Annotated[str, typer.Option("--ladder", help="spp of onepass's equal-time "
                      "ladder, comma-separated (stopped after the first frame slower than "
                      "the world's slowest method)")] = ",".join(map(str, LADDER_SPP)),
) -> None:
    """Evaluate methods on the scene suite against path-traced ground truth; write a report
    (Markdown, HTML, JSON, CSV, image grids, plots)."""
    from rich.console import Console

    from arlight.bounds import Estimate, check_estimate, check_range, estimate
    from arlight.evaluate.harness import EvalConfig, run_evaluation
    from arlight.evaluate.report import REPORT_FILES, write_report
    from arlight.evaluate.suite import get_scene, list_scenes
    from arlight.methods import available_methods
    from arlight.methods.spec import parse_option_pairs
    from arlight.staged_output import check_output_dir

    console = Console(stderr=True)
    if list_only:
        for name in list_scenes():
            s = get_scene(name)
            typer.echo(f"scene  {name:20s} {s.description}")
        for name, doc in available_methods().items():
            typer.echo(f"method {name:20s} {doc}")
        return
    from arlight.evaluate.variants import base_method
    from arlight.evaluate.worlds import parse_worlds

    known_methods, known_scenes = list(available_methods()), list_scenes()
    method_names = _names(methods, "methods") or known_methods
    seeds = parse_worlds(worlds) if worlds is not None else []
    scene_names = _names(scenes, "scenes") or ([] if seeds and scenes is None
                                                else known_scenes)
    for field, names, known in (("--methods", method_names, known_methods),
                                ("--scenes", scene_names, known_scenes)):
        unknown = [n for n in names if base_method(n) not in known]
        if unknown:
            raise InputError(f"unknown {', '.join(map(repr, unknown))}; available: "
                             f"{', '.join(known)}", field=field)
    sweep_spp = _ints(sweep, "sweep")
    for v in sweep_spp:
        check_range(v, "--sweep", 1, MAX_SPP)
    ladder_spp = _ints(ladder, "ladder")
    if not ladder_spp:
        raise InputError("expected at least one spp", field="--ladder")
    for v in ladder_spp:
        check_range(v, "--ladder", 1, MAX_SPP)
    total = 0.0
    world_w = width or (80 if quick else 640)
    sizes = [(n, get_scene(n, quick=quick).resolution) for n in scene_names] + [
        (f"world-{s}", (world_w, max(1, round(world_w * 3 / 4)))) for s in seeds]
    for name, (w, h) in sizes:
        one = estimate(w, h, max([spp, *sweep_spp]), paths=2)
        check_estimate(one, f"scene {name} ({w}×{h}, {spp} spp)", force)
        gt = estimate(w, h, gt_spp, paths=2)
        check_estimate(gt, f"the ground truth of {name} ({w}×{h}, {gt_spp} spp)", force)
        total += gt.seconds + len(method_names) * (
            one.seconds * (repeats + 1) + sum(estimate(w, h, s, paths=2).seconds
                                              for s in sweep_spp))
    check_estimate(Estimate(0.0, total, 0.0),  # the time over every cell; memory: above
                   f"{len(sizes)} scenes × {len(method_names)} methods", force)
    check_output_dir(out, REPORT_FILES, 64 << 20)
    cfg = EvalConfig(methods=method_names, scenes=scene_names, quick=quick, spp=spp,
                     gt_spp=gt_spp, repeats=repeats, seed=seed, max_depth=max_depth,
                     use_cache=not no_cache, cache_only=cache_only,
                     sweep_spp=sweep_spp,
                     options=parse_option_pairs(option or [], "[method.]key=value"),
                     worlds=seeds, world_width=width,
                     equal_time=bool(seeds) if equal_time is None else equal_time,
                     ladder_spp=ladder_spp)
    results = run_evaluation(cfg, log=console.print)
    paths = write_report(results, out)
    failed = sum(bool(c.error) for c in results.cells)
    skipped = sum(bool(c.skipped) for c in results.cells)
    console.print(f"report: {paths['markdown']} and {paths['html']} "
                  f"({len(results.cells)} cells, {failed} failed, {skipped} skipped, "
                  f"{results.seconds_total:.1f} s)")
