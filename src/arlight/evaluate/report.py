"""Write an evaluation report folder: Markdown + HTML pages, JSON/CSV, image grids, plots.

Layout of ``out/``::

    report.md, index.html     summary tables (Franke's grand-comparison shape per scene) and
                              the stage times (Franke Tables 5.2/5.6 shape: rows scene/method,
                              columns stages in ms)
    results.json, results.csv every number of every cell
    grids/<scene>__<method>.png  frame | composite | ground truth | signed error ×4
    plots/error_vs_spp.png, plots/error_vs_time.png   (when a spp sweep ran)
    plots/pareto_<class>.png  PSNR vs frame time per world class (generated worlds), with
                              onepass's time ladder
    errors/<scene>__<method>.txt tracebacks of failed cells

The error panel is the signed luminance error of the display image, scaled ×4 (Franke Fig.
5.19): blue → white where the composite is too bright, red → yellow where it is too dark.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from arlight.camera_response import Transfer
from arlight.evaluate import metrics as M
from arlight.evaluate.distribution import MethodRow, Spread, method_rows
from arlight.evaluate.harness import CellResult, EvalResults
from arlight.io.images import atomic_write

ERROR_GAIN = 4.0
SUMMARY_KEYS = ("seconds", "psnr", "flip", "ssim", "hdr_flip", "rmse", "changed_psnr",
                "changed_flip", "peak_mib", "samples")
STAGE_ORDER = ("prepare", "pose", "setup", "trace", "render", "assemble")
"""Usual stage order of the stage-time table; other stages follow in first-seen order."""


def _fmt(key: str, v: float) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    if key == "seconds":
        return f"{v * 1e3:.0f} ms" if v < 10 else f"{v:.1f} s"
    if "psnr" in key:
        return f"≥{M.PSNR_CAP:.0f} dB" if v >= M.PSNR_CAP else f"{v:.2f} dB"
    if key == "peak_mib":
        return f"{v:.0f} MiB"
    if key == "samples":
        return f"{v:.3g}"
    return f"{v:.4f}"


def _row(cell: CellResult) -> dict[str, float]:
    return {"seconds": cell.seconds, "peak_mib": cell.peak_mib,
            "samples": cell.stats.get("samples", math.nan), **cell.metrics}


def _md(text: str) -> str:
    """A Markdown table cell: no newlines, escaped pipes."""
    return str(text).replace("\n", " ").replace("|", "\\|")


def _slug(cell: CellResult) -> str:
    return f"{cell.scene}__{cell.method}"


def _write_text(path: Path, text: str) -> None:
    with atomic_write(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _save_fig(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    with atomic_write(path, ".png") as tmp:
        tmp.write_bytes(buf.getvalue())


def write_grid(cell: CellResult, path: Path) -> Path:
    """Frame | composite | ground truth | ×4 signed error, with a legend for the error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    tr = Transfer(cell.transfer_kind, exposure=cell.exposure)
    im = cell.images
    disp = {k: M.display(im[k], tr) for k in ("frame", "composite", "ground_truth")}
    err = M.signed_error(disp["composite"], disp["ground_truth"])
    h, w = err.shape
    fig, axes = plt.subplots(1, 4, figsize=(12.8, 12.8 / 4 * h / w + 0.9),
                             layout="constrained")
    titles = ["frame (input)", f"composite ({cell.method})", "ground truth",
              f"error ×{ERROR_GAIN:g} (blue: too bright, red: too dark)"]
    panels = [disp["frame"], disp["composite"], disp["ground_truth"],
              M.heatmap(err, ERROR_GAIN)]
    for ax, title, img in zip(axes, titles, panels, strict=True):
        ax.imshow(img, interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    ramp = np.linspace(-1.0, 1.0, 256) / ERROR_GAIN
    cmap = ListedColormap(M.heatmap(ramp[None, :], ERROR_GAIN)[0] / 255.0)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(-1 / ERROR_GAIN, 1 / ERROR_GAIN))
    cb = fig.colorbar(sm, ax=axes[3], orientation="horizontal", fraction=0.08, pad=0.02)
    cb.set_label("display-luminance error (composite − ground truth)", fontsize=8)
    fig.suptitle(f"{cell.scene}: {cell.method} — PSNR {_fmt('psnr', cell.metrics['psnr'])}, "
                 f"FLIP {cell.metrics['flip']:.4f}", fontsize=10)
    _save_fig(fig, path)
    return path


def write_plots(results: EvalResults, out: Path) -> list[Path]:
    """Error (RMSE of radiance, log-log) vs spp and vs wall time, one curve per cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = [c for c in results.cells if c.ok and c.sweep]
    if not cells:
        return []
    paths = []
    scenes = sorted({c.scene for c in cells})
    methods = sorted({c.method for c in cells})
    colour = {s: plt.get_cmap("tab10")(i % 10) for i, s in enumerate(scenes)}  # per scene
    style = {m: ("o-", "s--", "^:", "D-.")[i % 4] for i, m in enumerate(methods)}  # per method
    for xkey, xlabel, name in (("spp", "samples per pixel", "error_vs_spp"),
                               ("seconds", "wall time (s)", "error_vs_time")):
        fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
        for c in cells:
            xs = [getattr(p, xkey) for p in c.sweep]
            ax.loglog(xs, [p.rmse for p in c.sweep], style[c.method], color=colour[c.scene],
                      ms=4, label=f"{c.method} / {c.scene}")
        if xkey == "spp":  # Monte Carlo reference slope
            c0 = cells[0].sweep
            xs = np.array([p.spp for p in c0], float)
            ax.loglog(xs, c0[0].rmse * np.sqrt(xs[0] / xs), "k--", lw=0.8, label="∝ 1/√spp")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("RMSE of the composite (W/(sr·m²))")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        path = out / "plots" / f"{name}.png"
        _save_fig(fig, path)
        paths.append(path)
    return paths


def write_pareto(results: EvalResults, out: Path) -> list[Path]:
    """Per world class (and over all worlds): PSNR vs frame time, one small dot per method
    and world, a large marker at the method's medians, and onepass's time ladder (median
    time and median PSNR over the worlds at each spp)."""
    classes = results.world_classes()
    if not classes:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys(c.method for c in results.cells))
    colour = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    paths = []
    for group in ["all", *sorted(set(classes.values()))]:
        scenes = {s for s, k in classes.items() if group in ("all", k)}
        cells = [c for c in results.cells if c.ok and c.scene in scenes]
        if not cells:
            continue
        fig, ax = plt.subplots(figsize=(6.5, 4.5), layout="constrained")
        for m in methods:
            mine = [c for c in cells if c.method == m]
            if not mine:
                continue
            t = [c.seconds for c in mine]
            q = [c.metrics["psnr"] for c in mine]
            ax.scatter(t, q, s=8, alpha=0.35, color=colour[m])
            ax.scatter([np.median(t)], [np.median(q)], s=70, color=colour[m], label=m,
                       edgecolors="k")
        ladder: dict[int, list] = {}
        for name, pts in results.ladders.items():
            if name in scenes:
                for p in pts:
                    ladder.setdefault(p.spp, []).append(p)
        if ladder:
            spp = sorted(k for k, v in ladder.items() if len(v) * 2 >= len(scenes))
            ax.plot([np.median([p.seconds for p in ladder[k]]) for k in spp],
                    [np.median([p.metrics["psnr"] for p in ladder[k]]) for k in spp],
                    "k--", lw=1, label="onepass ladder (medians)")
        ax.set_xscale("log")
        ax.set_xlabel("frame time (s)")
        ax.set_ylabel("PSNR (dB, display)")
        ax.set_title(f"{group} worlds ({len(scenes)})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        path = out / "plots" / f"pareto_{group}.png"
        _save_fig(fig, path)
        paths.append(path)
    return paths


def _spread_text(sp: Spread, key: str) -> str:
    if sp.n == 0:
        return "—"
    if key == "seconds":
        return f"{sp.median * 1e3:.0f} / {sp.p10 * 1e3:.0f} / {sp.worst * 1e3:.0f} ms"
    fmt = "{:.4f}" if key == "flip" else "{:+.2f}" if key == "delta" else "{:.2f}"
    return " / ".join(fmt.format(v) for v in (sp.median, sp.p10, sp.worst))


WORLD_HEADER = ["method", "worlds run", "skipped", "failed", "PSNR dB", "PSNR changed dB",
                "FLIP", "frame time", "Δ PSNR vs onepass at equal time", "Δ changed",
                "wins vs onepass"]


def world_table(rows: list[MethodRow]) -> list[list[str]]:
    """Rows of the distribution table: each spread as median / 10th-percentile world /
    worst world."""
    return [[r.method, str(r.ran), str(r.skipped), str(r.failed),
             _spread_text(r.psnr, "psnr"), _spread_text(r.changed_psnr, "psnr"),
             _spread_text(r.flip, "flip"), _spread_text(r.seconds, "seconds"),
             _spread_text(r.equal_time_delta, "delta"),
             _spread_text(r.equal_time_changed_delta, "delta"),
             (f"{r.wins}/{r.compared}" + (f" ({r.no_onepass_frame} without an onepass "
                                          "frame that fast)" if r.no_onepass_frame else ""))
             if r.compared else "—"] for r in rows]


def _world_markdown(results: EvalResults) -> list[str]:
    classes = results.world_classes()
    if not classes:
        return []
    splits = sorted({results.scenes[s].get("split", "") for s in classes})
    rows = method_rows(results.cells, classes)
    lines = ["## Over generated worlds", "",
             f"{len(classes)} generated worlds ({', '.join(splits)}; seeds "
             f"{', '.join(s.removeprefix('world-') for s in classes)}). Classes: "
             + ", ".join(f"{k} {list(classes.values()).count(k)}"
                         for k in sorted(set(classes.values()))) + ". "
             "Each entry: median / 10th-percentile world (90 % of worlds do better) / worst "
             "world. Δ vs onepass: the method's PSNR minus that of the best onepass frame "
             "of the same world that took at most the method's frame time (worlds where "
             "onepass has no frame that fast count as wins and are left out of Δ). "
             "Training worlds tune; held-out worlds report (docs/testing.md).", ""]
    for group in dict.fromkeys(r.group for r in rows):
        mine = [r for r in rows if r.group == group]
        lines += [f"### {group} worlds", "", "| " + " | ".join(WORLD_HEADER) + " |",
                  "|" + "---|" * len(WORLD_HEADER)]
        lines += ["| " + " | ".join(_md(x) for x in r) + " |" for r in world_table(mine)]
        lines.append("")
    return lines


def _status(cell: CellResult) -> str:
    """'error: ...' or 'skipped: ...' for a cell without results ('' for a cell with)."""
    return f"error: {cell.error}" if cell.error else (
        f"skipped: {cell.skipped}" if cell.skipped else "")


def stage_names(results: EvalResults) -> list[str]:
    """Stages reported by any cell, in :data:`STAGE_ORDER` then first-seen order."""
    seen = dict.fromkeys(k for c in results.cells if c.ok for k in c.stages)
    return [k for k in STAGE_ORDER if k in seen] + [k for k in seen if k not in STAGE_ORDER]


def stage_table(results: EvalResults) -> tuple[list[str], list[list[str]]]:
    """Stage times in ms, Franke Tables 5.2/5.6 shape: one row per scene × method, one
    column per stage (``prepare`` once per world, the others of the median frame), then the
    sum of the frame's stages and the median frame time ("—": the method has no such stage;
    failed and skipped cells say why)."""
    names = stage_names(results)
    header = ["scene", "method", *names, "Σ frame stages", "frame"]
    rows = []
    for c in results.cells:
        if not c.ok:
            rows.append([c.scene, c.method, _status(c)] + [""] * (len(header) - 3))
            continue
        cols = [f"{c.stages[k] * 1e3:.2f}" if k in c.stages else "—" for k in names]
        per_frame = sum(v for k, v in c.stages.items() if k != "prepare")
        rows.append([c.scene, c.method, *cols, f"{per_frame * 1e3:.2f}",
                     f"{c.seconds * 1e3:.2f}"])
    return header, rows


def _tables(results: EvalResults) -> list[tuple[str, list[str], list[list[str]]]]:
    """Per scene: (title, header, rows) — Franke's grand comparison shape plus extras."""
    header = ["method", "time", "PSNR", "FLIP", "SSIM", "HDR-FLIP", "RMSE", "PSNR (changed)",
              "FLIP (changed)", "peak mem", "samples"]
    out = []
    for scene in dict.fromkeys(c.scene for c in results.cells):
        rows = []
        for c in (c for c in results.cells if c.scene == scene):
            if c.ok:
                r = _row(c)
                rows.append([c.method, *(_fmt(k, r.get(k, math.nan)) for k in SUMMARY_KEYS)])
            else:
                rows.append([c.method, _status(c)] + [""] * (len(header) - 2))
        info = results.scenes.get(scene, {})
        title = scene + (f" ({info['resolution']}) — {info['paper_figure']}" if info else "")
        out.append((title, header, rows))
    return out


def _markdown(results: EvalResults, grids: dict[str, str], plots: list[str]) -> str:
    cfg = results.config
    lines = ["# arlight evaluation report", "",
             f"Methods: {', '.join(cfg.methods)}; scenes: {', '.join(cfg.scenes)}; "
             f"{'quick' if cfg.quick else 'full'} resolution; method spp {cfg.spp}, "
             f"ground truth spp {cfg.gt_spp}; time = median of {cfg.repeats} warm runs; "
             f"total {results.seconds_total:.1f} s.", "",
             "PSNR = 10·log10(R²/MSE) on the display image (R = 1; Franke Eq. 5.28; "
             f"identical images: {M.PSNR_CAP:.0f} dB). FLIP = mean LDR-FLIP (0 = identical). "
             "'changed' = pixels the virtual objects cover or significantly relight.", ""]
    lines += ["## Grand comparison (Franke Fig. 5.19 shape)", "",
              "| method | scene | time | PSNR | FLIP |", "|---|---|---|---|---|"]
    for c in results.cells:
        cols = ([_fmt("seconds", c.seconds), _fmt("psnr", c.metrics["psnr"]),
                 _fmt("flip", c.metrics["flip"])] if c.ok else [_status(c), "", ""])
        lines.append("| " + " | ".join(_md(x) for x in [c.method, c.scene, *cols]) + " |")
    lines.append("")
    header, rows = stage_table(results)
    lines += ["## Stage times, ms (Franke Tables 5.2/5.6 shape)", "",
              f"The stages a method reports (`time_<stage>` in its stats; Dr.Jit synchronised "
              f"at each stage's end): `prepare` once per world, the others in the median of "
              f"{cfg.repeats} warm frames rendered from that state; 'frame' is that median "
              "wall time of `render(state, view)`, 'Σ frame stages' the part the stages "
              "cover.", "",
              "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md(x) for x in r) + " |" for r in rows]
    lines.append("")
    for title, header, rows in _tables(results):
        lines += [f"## {title}", "", "| " + " | ".join(header) + " |",
                  "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(_md(x) for x in r) + " |" for r in rows]
        lines.append("")
    lines += _world_markdown(results)
    if grids:
        lines += ["## Images", ""]
        lines += [f"![{k}]({v})" for k, v in grids.items()]
        lines.append("")
    if plots:
        lines += ["## Error vs samples and time", ""] + [f"![{p}]({p})" for p in plots] + [""]
    return "\n".join(lines)


def _html(results: EvalResults, grids: dict[str, str], plots: list[str]) -> str:
    e = html.escape
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>arlight evaluation"
             "</title><style>body{font-family:sans-serif;margin:2em}table{border-collapse:"
             "collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}"
             "td:first-child{text-align:left}.err{color:#b00;text-align:left}.skip{color:#777;"
             "text-align:left}img{max-width:"
             "100%}</style></head><body><h1>arlight evaluation report</h1>"]
    cfg = results.config
    parts.append(f"<p>{'quick' if cfg.quick else 'full'} resolution; method spp {cfg.spp}; "
                 f"ground truth spp {cfg.gt_spp}; time = median of {cfg.repeats} warm runs. "
                 f"PSNR on the display image (R = 1, Franke Eq. 5.28).</p>")
    header, rows = stage_table(results)
    world = ([(f"Over generated worlds — {r}: median / 10th percentile / worst", WORLD_HEADER,
               world_table([x for x in method_rows(results.cells, results.world_classes())
                            if x.group == r]))
              for r in ["all", *sorted(set(results.world_classes().values()))]]
             if results.world_classes() else [])
    tables = [*world, *_tables(results), ("Stage times, ms (Franke Tables 5.2/5.6 shape; stages of "
                                   "the median run, total = median wall time)", header, rows)]
    for title, header, rows in tables:
        parts.append(f"<h2>{e(title)}</h2><table><tr>"
                     + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr>")
        lead = 1 if header[0] == "method" else 2  # label columns before the status
        for r in rows:
            status = r[lead]
            if status.startswith(("error:", "skipped:")):
                cls = "err" if status.startswith("error:") else "skip"
                parts.append("<tr>" + "".join(f"<td>{e(x)}</td>" for x in r[:lead])
                             + f"<td class='{cls}' colspan='{len(header) - lead}'>"
                             f"{e(status)}</td></tr>")
            else:
                parts.append("<tr>" + "".join(f"<td>{e(x)}</td>" for x in r) + "</tr>")
        parts.append("</table>")
    for k, v in grids.items():
        parts.append(f"<h3>{e(k)}</h3><img src='{e(v)}' alt='{e(k)}'>")
    for p in plots:
        parts.append(f"<h3>{e(p)}</h3><img src='{e(p)}' alt='{e(p)}'>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _json(results: EvalResults) -> str:
    cfg = asdict(results.config)
    cfg["cache_dir"] = str(cfg["cache_dir"]) if cfg["cache_dir"] else None
    cells = []
    for c in results.cells:
        d = asdict(c)
        d.pop("images")
        d.pop("traceback")
        cells.append(d)

    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [clean(v) for v in x]
        return x

    header, rows = stage_table(results)
    dist = [asdict(r) for r in method_rows(results.cells, results.world_classes())] \
        if results.world_classes() else []
    ladders = {k: [asdict(p) for p in v] for k, v in results.ladders.items()}
    return json.dumps(clean({"config": cfg, "scenes": results.scenes, "cells": cells,
                             "stage_table_ms": {"header": header, "rows": rows},
                             "distribution": dist, "onepass_ladders": ladders,
                             "seconds_total": results.seconds_total}), indent=2)


REPORT_FILES = ("report.md", "index.html", "results.json", "results.csv", "grids", "plots",
                "errors")
"""Entries of a report folder (an existing folder of only these may be replaced)."""


def write_report(results: EvalResults, out: str | Path) -> dict[str, Path]:
    """Write the report folder; returns the paths of ``report.md``, ``index.html``, ....

    The report is staged next to ``out`` and swapped in as one set
    (:class:`arlight.staged_output.StagedOutput`): ``out`` holds the whole previous report
    or the whole new one; a folder holding other files is refused.
    """
    from arlight.staged_output import StagedOutput

    out = Path(out)
    with StagedOutput(out, "eval", REPORT_FILES) as tmp:
        staged = _write_report_files(results, tmp)
    return {k: out / p.relative_to(tmp) for k, p in staged.items()}


def _write_report_files(results: EvalResults, out: Path) -> dict[str, Path]:
    """Write every file of the report into the folder ``out``."""
    grids: dict[str, str] = {}
    for c in results.cells:
        if c.ok and c.images:
            rel = f"grids/{_slug(c)}.png"
            write_grid(c, out / rel)
            grids[f"{c.scene} × {c.method}"] = rel
        if c.traceback:
            _write_text(out / "errors" / f"{_slug(c)}.txt", c.traceback)
    plots = [str(p.relative_to(out)) for p in [*write_plots(results, out),
                                                *write_pareto(results, out)]]
    paths = {"markdown": out / "report.md", "html": out / "index.html",
             "json": out / "results.json", "csv": out / "results.csv"}
    _write_text(paths["markdown"], _markdown(results, grids, plots))
    _write_text(paths["html"], _html(results, grids, plots))
    _write_text(paths["json"], _json(results))
    keys = sorted({k for c in results.cells for k in c.metrics})
    stages = stage_names(results)
    buf = io.StringIO()
    wr = csv.writer(buf)
    wr.writerow(["scene", "method", "error", "skipped", "seconds", "peak_mib", "samples",
                 *(f"time_{k}" for k in stages), *keys])
    for c in results.cells:
        wr.writerow([c.scene, c.method, c.error, c.skipped, c.seconds, c.peak_mib,
                     c.stats.get("samples", ""), *(c.stages.get(k, "") for k in stages),
                     *(c.metrics.get(k, "") for k in keys)])
    _write_text(paths["csv"], buf.getvalue())
    return paths
