"""Every method's layers on every suite scene, before and after a change, compared bitwise.

The acceptance check of a refactoring that must not change any image (issue #29: moving
modules between packages): the old commit is checked out in a temporary ``git worktree``,
and a subprocess with ``PYTHONPATH=<worktree>/src`` renders every registered method on every
suite scene at a small size; then the same with the current tree (or ``--new``); then every
array of every :class:`~arlight.methods.Layers` is compared bit for bit.

    .venv/bin/python benchmarks/compare_layers.py                     # old = BASELINE
    .venv/bin/python benchmarks/compare_layers.py --old HEAD~3 --methods dlpv,dvct
    .venv/bin/python benchmarks/compare_layers.py --old abc123 --new def456 --allow dic
    .venv/bin/python benchmarks/compare_layers.py --old HEAD --new /path/to/other/checkout

Exit status: 0 when every compared cell is identical (or differs only in a method named by
``--allow``, reported), 1 when a layer differs or a cell renders on one side only, 2 on bad
usage. Progress goes to stderr, the table to stdout.

The renderer uses only API that exists before and after the move: ``arlight.methods``
(``available_methods``, ``get_method``, ``RenderSettings``), ``arlight.evaluate.suite``
(``list_scenes``, ``get_scene``, ``SuiteScene.photo``/``ar_scene``) and
``ARScene.resized``; if the suite module is missing it reads the scene folders
(``arlight/data/scenes/<name>/world.toml`` and ``proxy.toml``) with
``arlight.scene.load.load_scene``.

Scenes are loaded at their file resolution and resized to ``--size`` (width; the height
follows the file's aspect; the file size must be an integer multiple because the depth image
is box-filtered: 64 = 640/10 = 960/15). The frame is each tree's own synthetic photo of the
world (``--frame synth``; compared too, as the pseudo-method ``(frame)``) or a fixed
pattern that does not depend on the code under test (``--frame pattern``). Methods run with
small options (``SMALL``; ``--option method.key=value`` overrides, ``--default-options``
turns them off). A cell a method cannot render (its capabilities, or an InputError) is
skipped on both sides and listed; the same refusal on both sides is not a difference.
Each side gets its own empty ``ARLIGHT_CACHE`` (no PRT transfer or photo is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

BASELINE = "6245996bc879c42e9812d5a89fce8e1944b72d4a"
"""The commit before the #29 move (default ``--old``)."""

SMALL: dict[str, dict[str, object]] = {
    "dic": {"rays": 16},
    "dir": {"vpls": 64},
    "dlpv": {"volume_size": 16, "steps": 8, "rsm_size": 64},
    "dvct": {"volume_size": 32, "rsm_size": 64},
    "ibl": {"oof_shells": 8, "oof_directions": 256, "ao_rays": 8, "samples": 16},
    "nearfield": {"capture_size": 16, "capture_spp": 1, "atlas_resolution": 64, "vals": 4,
                  "directions": 64, "shadow_map_size": 32},
    "prt": {"oof_shells": 8, "oof_directions": 256, "directions": 256},
}
"""Per-method options that keep a cell to seconds at 64×48 (as in the tests; the atlas must
hold cornell-near-field's 11 charts)."""

FRAME = "(frame)"  # pseudo-method holding each scene's input frame


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- worker
def _scenes(names: list[str] | None, width: int, height: int | None):
    """(name, world, proxy) at ``width`` (height from the aspect, or ``height`` for scenes
    of that aspect); world/proxy are ARScenes."""
    try:
        from arlight.evaluate.suite import get_scene, list_scenes

        def load(name):
            s = get_scene(name, quick=False)
            return s, s.world, s.proxy
    except ImportError:  # no suite module: read the folders directly
        from importlib import resources

        from arlight.scene.load import load_scene

        root = Path(str(resources.files("arlight") / "data" / "scenes"))

        def list_scenes():
            return sorted(p.name for p in root.iterdir() if (p / "world.toml").is_file())

        def load(name):
            world = load_scene(root / name / "world.toml")
            proxy_path = root / name / "proxy.toml"
            return None, world, load_scene(proxy_path) if proxy_path.is_file() else world

    for name in names or list_scenes():
        suite, world, proxy = load(name)
        w0, h0 = world.resolution
        h = height if height and abs(height / width - h0 / w0) < 1e-9 else round(width * h0 / w0)
        yield name, suite, world.resized(width, h), proxy.resized(width, h)


def _pattern(h: int, w: int) -> np.ndarray:
    """A fixed frame: smooth ramps plus a deterministic texture, linear radiance in [0, 1]."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    rng = np.random.default_rng(1234)
    tex = rng.random((h, w, 3))
    base = np.stack([x / max(w - 1, 1), y / max(h - 1, 1), 0.5 + 0.0 * x], axis=-1)
    return (0.2 + 0.6 * base * (0.75 + 0.25 * tex)).astype(np.float32)


def _arrays(layers) -> dict[str, np.ndarray]:
    """Every array a Layers holds (fields that are arrays, and the stderr/other dicts of
    arrays), by name."""
    import dataclasses

    out: dict[str, np.ndarray] = {}
    fields = ([f.name for f in dataclasses.fields(layers)] if dataclasses.is_dataclass(layers)
              else list(vars(layers)))
    for name in fields:
        value = getattr(layers, name)
        if isinstance(value, np.ndarray):
            out[name] = value
        elif isinstance(value, dict):
            for k, v in value.items():
                if isinstance(v, np.ndarray):
                    out[f"{name}.{k}"] = v
    return out


def worker(a: argparse.Namespace) -> int:
    import arlight

    src = Path(a.tree).resolve() / "src"
    where = Path(arlight.__file__).resolve()
    if src not in where.parents:
        log(f"[{a.label}] arlight imported from {where}, not from {src}; aborting")
        return 3
    from arlight.errors import InputError
    from arlight.methods import RenderSettings, available_methods, get_method

    names = a.methods.split(",") if a.methods else list(available_methods())
    scenes = a.scenes.split(",") if a.scenes else None
    overrides: dict[str, dict[str, str]] = {}
    for pair in a.option:
        key, _, value = pair.partition("=")
        method, _, opt = key.partition(".")
        overrides.setdefault(method, {})[opt] = value
    arrays: dict[str, np.ndarray] = {}
    cells: dict[str, dict] = {}
    root = str(Path(a.tree).resolve())

    def scrub(text: str) -> str:  # paths differ between the two trees
        return text.replace(root, "<tree>")

    t_all = time.perf_counter()
    for scene_name, suite, world, proxy in _scenes(scenes, a.width, a.height):
        w, h = proxy.resolution
        t0 = time.perf_counter()
        if a.frame == "synth" and suite is not None:
            import dataclasses

            small = dataclasses.replace(suite, world=world, proxy=proxy)
            photo = small.photo(spp=a.spp, seed=a.seed, use_cache=False)
            frame = np.asarray(photo.frame, np.float32)
            arrays[f"{FRAME}/{scene_name}/frame"] = frame
            arrays[f"{FRAME}/{scene_name}/ground_truth"] = np.asarray(photo.ground_truth)
            scene = small.ar_scene(photo)
        else:
            frame = _pattern(h, w)
            arrays[f"{FRAME}/{scene_name}/frame"] = frame
            scene = proxy.with_frame(frame)
        cells[f"{FRAME}/{scene_name}"] = {"status": "ok",
                                          "seconds": time.perf_counter() - t0}
        log(f"[{a.label}] {scene_name}: {w}×{h}, frame in {time.perf_counter() - t0:.1f} s")
        for name in names:
            key = f"{name}/{scene_name}"
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                method = get_method(name)
                reason = method.spec.unsupported_reason(scene, scene)
                if reason:
                    cells[key] = {"status": "skipped", "why": scrub(reason)}
                    log(f"[{a.label}]   {name:<10} skipped: {reason}")
                    continue
                opts = {} if a.default_options else dict(SMALL.get(name, {}))
                opts = {k: v for k, v in opts.items() if k in method.spec.options}
                opts.update(overrides.get(name, {}))
                settings = RenderSettings(spp=a.spp, seed=a.seed, options=opts)
                layers = method(scene, settings)
            except InputError as exc:
                cells[key] = {"status": "refused", "why": scrub(f"InputError: {exc}")}
                log(f"[{a.label}]   {name:<10} refused: {exc}")
                continue
            except Exception as exc:  # noqa: BLE001 — report, compare, go on
                cells[key] = {"status": "error",
                              "why": scrub(f"{type(exc).__name__}: {exc}"),
                              "traceback": scrub(traceback.format_exc())}
                log(f"[{a.label}]   {name:<10} ERROR {type(exc).__name__}: {exc}")
                continue
            for layer, arr in _arrays(layers).items():
                arrays[f"{key}/{layer}"] = arr
            dt, cpu = time.perf_counter() - t0, time.process_time() - c0
            cells[key] = {"status": "ok", "seconds": dt, "cpu_seconds": cpu}
            log(f"[{a.label}]   {name:<10} {dt:6.2f} s ({cpu:.2f} s CPU)")
    np.savez(a.out, **arrays)
    meta = {"cells": cells, "arlight": str(where), "seconds": time.perf_counter() - t_all,
            "cpu_seconds": time.process_time(), "methods": names}
    Path(a.out).with_suffix(".json").write_text(json.dumps(meta, indent=1))
    log(f"[{a.label}] rendered in {meta['seconds']:.1f} s ({meta['cpu_seconds']:.1f} s CPU)")
    return 0


# ------------------------------------------------------------------------- comparison
def _render_side(label: str, tree: Path, out: Path, a: argparse.Namespace,
                 cache: Path) -> subprocess.Popen:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--label", label,
           "--tree", str(tree), "--out", str(out), "--spp", str(a.spp), "--seed", str(a.seed),
           "--size", a.size, "--frame", a.frame]
    if a.methods:
        cmd += ["--methods", a.methods]
    if a.scenes:
        cmd += ["--scenes", a.scenes]
    if a.default_options:
        cmd.append("--default-options")
    for pair in a.option:
        cmd += ["--option", pair]
    env = {**os.environ, "PYTHONPATH": str(tree / "src"), "ARLIGHT_CACHE": str(cache),
           "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.Popen(cmd, env=env, cwd=str(tree))


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO), *args], check=True, capture_output=True,
                          text=True).stdout.strip()


def _worktree(rev: str, parent: Path, label: str) -> tuple[Path, str]:
    commit = _git("rev-parse", "--verify", f"{rev}^{{commit}}")
    path = parent / label
    _git("worktree", "add", "--detach", "--quiet", str(path), commit)
    return path, commit


def compare(old: Path, new: Path, allow: set[str]) -> tuple[list[tuple], bool]:
    """Rows (method, scene, verdict, detail) and whether everything passes."""
    a, b = np.load(old), np.load(new)
    ma = json.loads(old.with_suffix(".json").read_text())["cells"]
    mb = json.loads(new.with_suffix(".json").read_text())["cells"]
    rows, ok = [], True
    for key in sorted(set(ma) | set(mb), key=lambda k: (k.split("/")[0] != FRAME, k)):
        method, scene = key.split("/")
        ca, cb = ma.get(key, {"status": "absent"}), mb.get(key, {"status": "absent"})
        allowed = method in allow
        if ca["status"] != "ok" or cb["status"] != "ok":
            same = ca["status"] == cb["status"] and ca.get("why") == cb.get("why")
            if same:
                rows.append((method, scene, ca["status"], ca.get("why", "")))
                if ca["status"] == "error":
                    ok = ok and allowed  # an error on both sides is no evidence either way
                continue
            rows.append((method, scene, "DIFFERS" + (" (allowed)" if allowed else ""),
                         f"old {ca['status']} {ca.get('why', '')} / new {cb['status']} "
                         f"{cb.get('why', '')}".strip()))
            ok = ok and allowed
            continue
        prefix = key + "/"
        la = {k[len(prefix):] for k in a.files if k.startswith(prefix)}
        lb = {k[len(prefix):] for k in b.files if k.startswith(prefix)}
        diffs = []
        for layer in sorted(la | lb):
            if layer not in la or layer not in lb:
                diffs.append(f"{layer}: only {'old' if layer in la else 'new'}")
                continue
            x, y = a[prefix + layer], b[prefix + layer]
            if x.shape != y.shape or x.dtype != y.dtype:
                diffs.append(f"{layer}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}")
                continue
            bx = x.view(np.uint8).reshape(*x.shape, -1) if x.size else x
            by = y.view(np.uint8).reshape(*y.shape, -1) if y.size else y
            if np.array_equal(bx, by):
                continue
            differ = (bx != by).reshape(x.shape[0], -1).any(axis=1) if x.ndim < 2 else \
                (bx != by).reshape(x.shape[0], x.shape[1], -1).any(axis=-1)
            with np.errstate(invalid="ignore", over="ignore"):
                diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
            mx = np.nanmax(np.where(np.isfinite(diff), diff, np.nan)) if np.isfinite(
                diff).any() else float("nan")
            diffs.append(f"{layer}: {int(differ.sum())} px differ, max |Δ| {mx:.3g}")
        if diffs:
            rows.append((method, scene, "DIFFERS" + (" (allowed)" if allowed else ""),
                         "; ".join(diffs)))
            ok = ok and allowed
        else:
            rows.append((method, scene, "identical", f"{len(la)} arrays"))
    return rows, ok


def _table(rows: list[tuple]) -> str:
    w = [max(len(str(r[i])) for r in rows + [("method", "scene", "verdict")])
         for i in range(3)]
    lines = [f"{'method':<{w[0]}}  {'scene':<{w[1]}}  {'verdict':<{w[2]}}  detail"]
    lines += [f"{m:<{w[0]}}  {s:<{w[1]}}  {v:<{w[2]}}  {d}" for m, s, v, d in rows]
    return "\n".join(lines)


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--old", default=BASELINE,
                   help=f"commit to compare against (default: BASELINE = {BASELINE[:10]})")
    p.add_argument("--new", default=None,
                   help="commit, or a directory holding a source tree (default: this "
                        "working tree, uncommitted changes included)")
    p.add_argument("--size", default="64x48",
                   help="WIDTHxHEIGHT (default 64x48); scenes of another aspect keep theirs")
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--methods", help="comma-separated (default: every available method)")
    p.add_argument("--scenes", help="comma-separated suite scenes (default: all)")
    p.add_argument("--option", action="append", default=[], metavar="METHOD.KEY=VALUE",
                   help="method option, overriding SMALL (repeatable)")
    p.add_argument("--default-options", action="store_true",
                   help="the methods' default options instead of SMALL")
    p.add_argument("--frame", choices=("synth", "pattern"), default="synth",
                   help="the input frame: each tree's synthetic photo (default), or a fixed "
                        "pattern independent of the code")
    p.add_argument("--allow", action="append", default=[], metavar="METHOD",
                   help="a method that may differ (reported, not failed; repeatable)")
    p.add_argument("--parallel", action="store_true",
                   help="render both sides at once (needs twice the cores)")
    p.add_argument("--keep", type=Path, help="keep the .npz/.json of both sides here")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--label", default="", help=argparse.SUPPRESS)
    p.add_argument("--tree", help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    m = re.fullmatch(r"(\d+)(?:x(\d+))?", a.size)
    if not m or a.spp < 1:
        p.error(f"--size WIDTHxHEIGHT and --spp >= 1 (got {a.size!r}, {a.spp})")
    a.width, a.height = int(m[1]), int(m[2]) if m[2] else None
    for pair in a.option:
        if not re.fullmatch(r"[\w-]+\.\w+=.*", pair):
            p.error(f"--option METHOD.KEY=VALUE, got {pair!r}")
    return a


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    if a.worker:
        return worker(a)
    allow = {m for x in a.allow for m in x.split(",")}
    tmp = Path(tempfile.mkdtemp(prefix="compare-layers-"))
    trees: list[Path] = []
    t0 = time.perf_counter()
    try:
        old_tree, old_commit = _worktree(a.old, tmp, "old")
        trees.append(old_tree)
        if a.new is None:
            new_tree, new_desc = REPO, f"working tree {REPO}"
        elif Path(a.new).is_dir():
            new_tree, new_desc = Path(a.new).resolve(), f"tree {a.new}"
        else:
            new_tree, new_commit = _worktree(a.new, tmp, "new")
            trees.append(new_tree)
            new_desc = f"commit {new_commit}"
        log(f"old: commit {old_commit} ({old_tree})\nnew: {new_desc}")
        out = a.keep or tmp
        out.mkdir(parents=True, exist_ok=True)
        sides = [("old", old_tree), ("new", new_tree)]
        procs = []
        for label, tree in sides:
            cache = tmp / f"cache-{label}"
            proc = _render_side(label, tree, out / f"{label}.npz", a, cache)
            if a.parallel:
                procs.append(proc)
            elif proc.wait() != 0:
                log(f"{label} side failed (exit {proc.returncode})")
                return 1
        for proc, (label, _) in zip(procs, sides, strict=False):
            if proc.wait() != 0:
                log(f"{label} side failed (exit {proc.returncode})")
                return 1
        rows, ok = compare(out / "old.npz", out / "new.npz", allow)
        print(f"old {old_commit[:12]}  vs  new {new_desc}   size {a.size}, spp {a.spp}, "
              f"seed {a.seed}, frame {a.frame}")
        print(_table(rows))
        counts: dict[str, int] = {}
        for r in rows:
            counts[r[2].split(" ")[0]] = counts.get(r[2].split(" ")[0], 0) + 1
        print(f"\n{', '.join(f'{v} {k}' for k, v in sorted(counts.items()))}; "
              f"{'PASS' if ok else 'FAIL'} in {time.perf_counter() - t0:.0f} s")
        return 0 if ok else 1
    finally:
        for tree in trees:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(tree)], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
