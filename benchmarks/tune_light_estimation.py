"""Re-choose two light-estimation constants on training worlds, report them on held-out
worlds (issue #30).

* **probeless** (Gruber 2014): the Tikhonov weight ``ridge`` of the SH light fit (E5). Per
  generated world (:mod:`arlight.evaluate.worlds`, 160×120, ground truth 256 spp, seed 1,
  depth 8): the method's own pipeline (ART4, one frame, the proxy with the sensor depth and
  the synthetic frame) gives the observations of E5 once; every ``ridge`` of the grid solves
  E5 on them. The estimate is compared with the **true SH of the light arriving at the
  virtual objects** (centre of their bounding box, the world's real part, i.e. the frame's
  light): :func:`arlight.probeless.experiment.incident_sh` — Mitsuba's emitter sampling for
  the emitted light seen directly (every light type, visibility tested) plus Mitsuba's path
  tracer with the directly seen emitters hidden for the reflected light, both projected on
  the 16 SH. Measures: relative SH error ``‖l − l_true‖/‖l_true‖`` and the upper-hemisphere
  radiance error (:func:`~arlight.probeless.experiment.upper_hemisphere_error`), and through
  the harness (:func:`arlight.evaluate.harness.evaluate_cell`) the composite's PSNR / FLIP
  over the image and over the changed region. The ridge is chosen by the **median relative
  SH error over the training worlds** (ties: the smaller weight).
* **nearfield** (Rohmer 2015): the direct share ``τ``. Applicable to **rooms** (the proxy
  surrounds the objects, so the light reaching them is on the radiance atlas); tabletops and
  outdoor grounds get their light from the sky, which is on no proxy surface (counted as
  skips). Per room: the method's automatic rig (six 128² fisheyes inside the proxy's bounds,
  those that see the proxy) captured by Mitsuba's path tracer in the **world** (what real
  cameras see, 32 spp), the server on the proxy for every ``τ`` of the grid, the light state
  given to the method (option ``light``) through the harness. ``τ`` is chosen by the
  **median changed-region PSNR over the training rooms** (ties: the old value).

* **probeless on light setups** (``--part setups``, issue #33): the radius of the
  reconstruction's plane-fit normals (:data:`arlight.probeless.reconstruct.NORMAL_RADIUS`,
  chosen first by the normals' mean angle to the exact room's on the training sequences'
  reconstructions), then the ridge and the visibility range ``max_distance`` (Gruber: 10 cm;
  the reconstruction's Taubin smoothing,
  :data:`arlight.probeless.reconstruct.SMOOTH_ITERATIONS`, chosen the same way in the first
  run and fixed since) on the modelled room of
  ``bench_probeless.py`` (8 frames, 160×120, static and moving camera, reconstructed with
  the TSDF, ART4), where the true SH of each frame is known exactly. **Training setups**:
  the room under the real HDR maps (``studio_small_03``, ``rooitou_park``, the bundled
  ``lebombo``), path traced with interreflection (depth 8) as real frames are; **held-out**:
  Gruber's own light, the animated SH cap light, direct light only as his renderings.
  Chosen by the median over the distant-light training sequences of the mean
  upper-hemisphere error (ties: the smaller value), among the candidates that keep a near
  lamp's direction (training sequences of the room under bunny-box's lamp,
  :data:`LAMP_DOT_LOSS`); the held-out setups are reported, old and new constants in the
  same run. ``--part decompose`` prints what limits the estimate (inputs replaced by the
  truth one after another, :func:`decompose`); ``--part setups`` appends it.

Old and new values run on the same held-out worlds in the same run. Per-world results are
cached (``~/.cache/arlight/tune_light``), so a rerun only re-tabulates. Usage:

    .venv/bin/python benchmarks/tune_light_estimation.py [--train 12] [--heldout 24]
        [--rooms-train 8] [--rooms-heldout 12]
        [--part probeless|nearfield|setups|decompose|all]
        [--write]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import cpu_pressure, publish  # noqa: E402

from arlight.cache import default_cache_dir  # noqa: E402
from arlight.evaluate.harness import EvalConfig, evaluate_cell  # noqa: E402
from arlight.evaluate.worlds import (  # noqa: E402
    GENERATOR_VERSION,
    generate,
    parse_worlds,
    split_seeds,
)

HEADING = ("## Held-out worlds: probeless and nearfield constants re-chosen on training "
           "worlds (issue #30)")
WIDTH = 160
GT = {"spp": 256, "seed": 1, "max_depth": 8}
RIDGES = [0.0, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1]
OLD_RIDGE = 3e-3
TAUS = [0.3, 0.45, 0.6, 0.75, 0.9]
OLD_TAU = 0.6
VERSION = 1
"""Bump when a per-world record would change (measures, settings)."""
METRICS = ("psnr", "flip", "changed_psnr", "changed_flip")
NOTE = (
    "Smaller than planned (12 training / 24 held-out): on the shared 2-core machine (CPU "
    "pressure ≈ 100 % throughout) a room's ground truth took 2–7 min and its fisheye capture "
    "2–14 min, so the recorded run used the first 11 held-out worlds for probeless, 2 training "
    "and 4 held-out rooms for nearfield (`--heldout 11 --rooms-train 2 --nearfield-heldout "
    "1000001,1000004,1000016,1000021`). **Neither training choice became the default**: both "
    "were worse on the held-out worlds (probeless 0.1 on the median of every light measure, "
    "nearfield 0.75 on all 4 rooms), and both were thin — probeless's at the grid's edge on 4 "
    "determined worlds by a criterion that rewards shrinking toward the zero estimate "
    "(error 1.0), nearfield's on 2 rooms, one indifferent to τ. Keeping the old values after "
    "seeing held-out numbers is itself informed by them; docs/methods/probeless.md and "
    "nearfield.md say so. On training evidence alone the change was not supported either: "
    "the image metric on the training worlds favours the old ridge (changed-region PSNR "
    "20.17 vs 19.67 dB), and τ = 0.75 rests on one room by 0.26 dB with the other flat "
    "within 0.25 dB. Because these held-out worlds have now informed a decision, a later "
    "re-choice of ridge or τ reports on held-out seeds from 1 000 024 on.")


def cache_dir() -> Path:
    d = default_cache_dir() / "tune_light"
    d.mkdir(parents=True, exist_ok=True)
    return d


def cached(name: str, make):
    """The JSON record ``name`` from the cache, or ``make()`` stored there."""
    path = cache_dir() / f"{name}-g{GENERATOR_VERSION}-v{VERSION}.json"
    if path.exists():
        return json.loads(path.read_text())
    rec = make()
    path.write_text(json.dumps(rec))
    return rec


def world_info(gw) -> dict:
    t = gw.tags
    return {"seed": gw.seed, "class": gw.world_class, "env": t["env"], "sun": bool(t["sun"]),
            "lights": [x["type"] for x in t["lights"]], "open": t.get("room_open", "")}


def harness(method: str, scene, photo, options: dict) -> dict:
    cfg = EvalConfig(methods=[method], scenes=[scene.name], repeats=1, max_depth=GT["max_depth"],
                     gt_spp=GT["spp"])
    cell = evaluate_cell(method, scene, photo, cfg, options)
    if cell.skipped:
        return {"skipped": cell.skipped}
    if cell.error:
        return {"error": cell.error}
    return {**{k: float(cell.metrics[k]) for k in METRICS}, "seconds": cell.seconds,
            "stats": {k: v for k, v in cell.stats.items() if k.startswith("light_")}}


# ------------------------------------------------------------------------------ probeless

def probeless_world(seed: int) -> dict:
    from arlight.backend.mitsuba_scene import build_views
    from arlight.probeless.estimate import estimate_light
    from arlight.probeless.experiment import (
        incident_sh,
        object_centre,
        upper_hemisphere_error,
    )
    from arlight.probeless.pipeline import Pipeline, Settings

    gw = generate(seed)
    scene = gw.suite_scene(WIDTH)
    photo = scene.photo(**GT)
    rec = world_info(gw)
    t0 = time.perf_counter()
    truth = incident_sh(scene.world.world, object_centre(scene.world.world),
                        directions=4096, spp=8)
    rec["truth_seconds"] = time.perf_counter() - t0
    ar = scene.ar_scene(photo)
    world = ar.world
    pipe = Pipeline(build_views(world), "ART4", Settings(), shapes=world.shapes)
    res = pipe.process(ar.camera, ar.frame, ar.depth, shade=False)
    obs = res.observations
    rec["samples"] = int(len(obs[0]))
    rec["rank"] = int(res.fit.rank)
    rec["determined"] = bool(res.fit.determined)
    rec["truth_norm"] = float(np.linalg.norm(truth))
    rows = {}
    for r in RIDGES:
        fit = estimate_light(*obs, ridge=r)
        rows[repr(r)] = {
            "sh_error": float(np.linalg.norm(fit.sh - truth) / np.linalg.norm(truth)),
            "upper_error": upper_hemisphere_error(fit.sh, truth),
            "dot": float(fit.direction @ _unit(truth)),
        }
    rec["light"] = rows
    rec["composite"] = {}
    return rec


def with_composites(name: str, rec: dict, keys: list[str], factory) -> dict:
    """``rec`` with ``rec["composite"][k] = factory()(k)`` for the keys it lacks (stored)."""
    todo = [k for k in keys if k not in rec["composite"]]
    if todo:
        make = factory()
        for k in todo:
            rec["composite"][k] = make(k)
        (cache_dir() / f"{name}-g{GENERATOR_VERSION}-v{VERSION}.json").write_text(
            json.dumps(rec))
    return rec


def probeless_composite(seed: int):
    scene = generate(seed).suite_scene(WIDTH)
    photo = scene.photo(**GT)
    return lambda k: harness("probeless", scene, photo, {"ridge": float(k)})


def _unit(sh: np.ndarray) -> np.ndarray:
    from arlight.sphere import sh as SH

    return SH.dominant_direction(sh)


# ------------------------------------------------------------------------------ nearfield

NEARFIELD_CLASSES = ("room",)


def nearfield_world(seed: int) -> dict:
    from arlight.methods.nearfield import OPTIONS, SPEC
    from arlight.nearfield.cameras import default_rig, seeing_cameras
    from arlight.nearfield.capture import capture_rig
    from arlight.nearfield.lightfile import save_light
    from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings

    gw = generate(seed)
    rec = world_info(gw)
    if gw.world_class not in NEARFIELD_CLASSES:
        rec["skipped"] = (f"{gw.world_class}: its light comes from the sky, which lies on no "
                          "proxy surface (nothing for the radiance atlas to capture)")
        return rec
    scene = gw.suite_scene(WIDTH)
    proxy = scene.proxy.world
    reason = SPEC.unsupported_reason(proxy)
    if reason:
        rec["skipped"] = reason
        return rec
    photo = scene.photo(**GT)
    size, spp = OPTIONS["capture_size"].default, OPTIONS["capture_spp"].default
    rig = default_rig(proxy, size)
    t0 = time.perf_counter()
    server = NearFieldServer(proxy, rig, NearFieldSettings())
    server.cameras = seeing_cameras(rig, server.geometry, server.proxy_scene)
    images = capture_rig(scene.world.world, server.cameras, spp)  # the world, not the proxy
    rec["capture_seconds"] = time.perf_counter() - t0
    rec["cameras"] = len(server.cameras)
    rows = {}
    for tau in TAUS:  # a fresh server per τ: one update from k-means++, as the method's
        srv = NearFieldServer(proxy, server.cameras, NearFieldSettings(tau=tau))
        light = srv.update(images, timestamp=0.0)
        path = cache_dir() / f"nearfield-light-{seed}-{tau}.json"
        save_light(light, path)
        rows[repr(tau)] = harness("nearfield", scene, photo, {"light": str(path)})
        rows[repr(tau)]["vals"] = int(light.count)
    rec["composite"] = rows
    return rec


# ------------------------------------------------------------------------------ tables

def _q(values: list[float], higher_better: bool) -> tuple[float, float, float]:
    """(median, the worst decile's edge, worst): p90 and max of an error, p10 and min of a
    PSNR."""
    a = np.asarray(values, float)
    if higher_better:
        return float(np.median(a)), float(np.percentile(a, 10)), float(a.min())
    return float(np.median(a)), float(np.percentile(a, 90)), float(a.max())


def _fmt(q: tuple[float, float, float], digits: int = 3) -> str:
    return " / ".join(f"{x:.{digits}f}" for x in q)


def light_rows(recs: list[dict]) -> list[dict]:
    """The records whose light is determined (others are skips)."""
    return [r for r in recs if r["determined"]]


def probeless_skips(recs: list[dict]) -> list[str]:
    return [f"{r['seed']} ({r['class']}): light undetermined (rank {r['rank']} of 16)"
            for r in recs if not r["determined"]]


def composite_skips(recs: list[dict], key: str) -> list[str]:
    out = []
    for r in recs:
        c = r["composite"].get(key, {})
        if "skipped" in c or "error" in c:
            out.append(f"{r['seed']} ({r['class']}): {c.get('skipped') or c.get('error')}")
    return out


def composite_ok(recs: list[dict], key: str) -> list[dict]:
    """The composites of ``key`` that ran (absent: not run for that key)."""
    out = [r.get("composite", {}).get(key) for r in recs]
    return [c for c in out if c is not None and "skipped" not in c and "error" not in c]


def choose(recs: list[dict], keys: list[str], score, old: str, higher_better: bool
           ) -> tuple[str, dict[str, float]]:
    """The key with the best median score over ``recs`` (ties: ``old``, then the first)."""
    med = {k: float(np.median([score(r, k) for r in recs])) for k in keys}
    best = max(med.values()) if higher_better else min(med.values())
    pick = old if abs(med[old] - best) <= 1e-12 else next(k for k in keys if med[k] == best)
    return pick, med


def probeless_section(train: list[dict], held: list[dict]) -> tuple[str, float]:
    keys = [repr(r) for r in RIDGES]
    old = repr(OLD_RIDGE)
    tl = light_rows(train)
    pick, med = choose(tl, keys, lambda r, k: r["light"][k]["sh_error"], old, False)
    lines = ["### probeless: the ridge weight of the light fit (E5)", "",
             f"Training: {len(train)} worlds, {len(tl)} with a determined light. Grid "
             f"`ridge` ∈ {{{', '.join(f'{r:g}' for r in RIDGES)}}}; criterion: median "
             "relative SH error over the training worlds.", "",
             "| ridge | median SH error | median upper-hemisphere error | median dot | "
             "median changed-region PSNR (dB) | worlds with a composite |",
             "|---|---|---|---|---|---|"]
    for k in keys:
        comp = composite_ok(train, k)
        lines.append(
            f"| {float(k):g}{' (old)' if k == old else ''}"
            f"{' **training choice**' if k == pick else ''}"
            f" | {med[k]:.3f} | "
            f"{np.median([r['light'][k]['upper_error'] for r in tl]):.3f} | "
            f"{np.median([r['light'][k]['dot'] for r in tl]):.3f} | "
            + (f"{np.median([c['changed_psnr'] for c in comp]):.2f}" if comp else "—")
            + f" | {len(comp)} |")
    hl = light_rows(held)
    lines += ["", f"Held-out: {len(held)} worlds, {len(hl)} with a determined light; "
              "median / worst 10 % (p90 of an error, p10 of a PSNR) / worst.", "",
              "| measure | old ridge = " + f"{OLD_RIDGE:g}" + " | new ridge = "
              + f"{float(pick):g} |", "|---|---|---|"]
    for name, field, hb in (("relative SH error", "sh_error", False),
                            ("upper-hemisphere error", "upper_error", False),
                            ("dot(d_est, d_true)", "dot", True)):
        cells = [_fmt(_q([r["light"][k][field] for r in hl], hb)) for k in (old, pick)]
        lines.append(f"| {name} | {cells[0]} | {cells[1]} |")
    for name, field, hb, dg in (("PSNR (dB)", "psnr", True, 2),
                                ("changed-region PSNR (dB)", "changed_psnr", True, 2),
                                ("FLIP", "flip", False, 4),
                                ("changed-region FLIP", "changed_flip", False, 4)):
        cells = []
        for k in (old, pick):
            comp = composite_ok(held, k)
            cells.append(_fmt(_q([c[field] for c in comp], hb), dg) if comp else "—")
        lines.append(f"| {name} ({len(composite_ok(held, old))} worlds) | {cells[0]} | "
                     f"{cells[1]} |")
    skips = probeless_skips(train + held)
    cskips = composite_skips([r for r in held if r["determined"]], old)
    from arlight.probeless.estimate import DEFAULT_RIDGE

    lines += ["", f"Default after this run: ridge = {DEFAULT_RIDGE:g} "
              "(`arlight.probeless.estimate.DEFAULT_RIDGE`; docs/methods/probeless.md says "
              "why it is or is not the training choice)."]
    lines += ["", f"Light skips (training + held-out): {len(skips)}"
              + (": " + "; ".join(skips) if skips else "") + ".",
              f"Composite skips on held-out worlds ({len(cskips)} of {len(hl)}): "
              + ("; ".join(cskips) if cskips else "none") + "."]
    return "\n".join(lines), float(pick)


def probeless_distribution(held: list[dict], ridge: float) -> str:
    """The RESULTS.md probeless claim (dominant direction within ~0.94–0.98 dot on the
    modelled room) restated on held-out worlds, by class and by what lights them."""
    k = repr(ridge)
    hl = light_rows(held)
    groups: dict[str, list[dict]] = {"all": hl}
    for cls in ("tabletop", "room", "outdoor"):
        groups[cls] = [r for r in hl if r["class"] == cls]
    groups["distant light only (environment / sun)"] = [r for r in hl if not r["lights"]]
    groups["with local lights"] = [r for r in hl if r["lights"]]
    lines = [f"### probeless light error on held-out worlds (ridge = {ridge:g})", "",
             "Median / worst 10 % / worst; the truth is the SH of the light arriving at the "
             "virtual objects (`arlight.probeless.experiment.incident_sh`).", "",
             "| worlds | N | relative SH error | upper-hemisphere error | "
             "dot(d_est, d_true) |", "|---|---|---|---|---|"]
    for name, rs in groups.items():
        if not rs:
            continue
        lines.append(f"| {name} | {len(rs)} | "
                     f"{_fmt(_q([r['light'][k]['sh_error'] for r in rs], False), 2)} | "
                     f"{_fmt(_q([r['light'][k]['upper_error'] for r in rs], False), 2)} | "
                     f"{_fmt(_q([r['light'][k]['dot'] for r in rs], True), 2)} |")
    lines += ["", "Per world (seed, class, lights: SH error, upper error, dot): "
              + "; ".join(f"{r['seed']} {r['class']} {'+'.join(r['lights']) or r['env']}: "
                          f"{r['light'][k]['sh_error']:.2f}, "
                          f"{r['light'][k]['upper_error']:.2f}, {r['light'][k]['dot']:.2f}"
                          for r in hl) + "."]
    return "\n".join(lines)


def nearfield_section(train: list[dict], held: list[dict]) -> tuple[str, float]:
    keys = [repr(t) for t in TAUS]
    old = repr(OLD_TAU)
    tr = [r for r in train if "skipped" not in r and composite_ok([r], old)]
    pick, med = choose(tr, keys, lambda r, k: r["composite"][k]["changed_psnr"], old, True)
    lines = ["### nearfield: the direct share τ", "",
             f"Training: {len(tr)} rooms (seeds {', '.join(str(r['seed']) for r in tr)}). "
             f"Grid τ ∈ {{{', '.join(f'{t:g}' for t in TAUS)}}}; criterion: median "
             "changed-region PSNR over the training rooms.", "",
             "| τ | median changed-region PSNR (dB) | median PSNR (dB) | median FLIP |",
             "|---|---|---|---|"]
    for k in keys:
        lines.append(f"| {float(k):g}{' (old)' if k == old else ''}"
                     f"{' **training choice**' if k == pick else ''} | {med[k]:.2f} | "
                     f"{np.median([r['composite'][k]['psnr'] for r in tr]):.2f} | "
                     f"{np.median([r['composite'][k]['flip'] for r in tr]):.4f} |")
    hr = [r for r in held if "skipped" not in r and composite_ok([r], old)]
    lines += ["", f"Held-out: {len(hr)} rooms (seeds {', '.join(str(r['seed']) for r in hr)}"
              "); median / worst 10 % / worst.", "",
              f"| measure | old τ = {OLD_TAU:g} | new τ = {float(pick):g} |", "|---|---|---|"]
    for name, field, hb, dg in (("PSNR (dB)", "psnr", True, 2),
                                ("changed-region PSNR (dB)", "changed_psnr", True, 2),
                                ("FLIP", "flip", False, 4),
                                ("changed-region FLIP", "changed_flip", False, 4)):
        cells = [_fmt(_q([r["composite"][k][field] for r in hr], hb), dg) for k in (old, pick)]
        lines.append(f"| {name} | {cells[0]} | {cells[1]} |")
    diff = [r["composite"][pick]["changed_psnr"] - r["composite"][old]["changed_psnr"]
            for r in hr]
    if diff:
        lines += ["", "Per held-out room, new − old changed-region PSNR (dB): "
                  + ", ".join(f"{r['seed']}: {d:+.2f}" for r, d in zip(hr, diff, strict=True))
                  + f" (better on {sum(d > 0 for d in diff)}, worse on "
                  f"{sum(d < 0 for d in diff)})."]
    skips = [f"{r['seed']} ({r['class']}): {r['skipped']}" for r in train + held
             if "skipped" in r]
    from arlight.nearfield.split import DEFAULT_TAU

    lines += ["", f"Default after this run: τ = {DEFAULT_TAU:g} "
              "(`arlight.nearfield.split.DEFAULT_TAU`).",
              "", f"Skips ({len(skips)}): " + "; ".join(skips) + "."]
    return "\n".join(lines), float(pick)


def nearfield_seeds(split: str, first: int, rooms: int) -> list[int]:
    """The first ``first`` seeds of ``split`` plus further seeds until ``rooms`` applicable
    rooms (shapes and materials the method supports) are among them."""
    from arlight.methods.nearfield import SPEC
    from arlight.scene.load import parse_world

    seeds = split_seeds(split, first)
    n_ok = 0
    for s in split_seeds(split, 400):
        gw = generate(s)
        ok = gw.world_class in NEARFIELD_CLASSES and not SPEC.unsupported_reason(
            parse_world(gw.proxy))
        if s in seeds:
            n_ok += ok
        elif n_ok < rooms and ok:
            seeds.append(s)
            n_ok += 1
        if n_ok >= rooms and s >= seeds[first - 1]:
            break
    return seeds


SETUPS_HEADING = ("## Probeless: ridge, reconstruction smoothing and visibility range chosen "
                  "on training light setups, reported on Gruber's (issue #33)")
SMOOTHING = 100
"""Taubin passes (:data:`arlight.probeless.reconstruct.SMOOTH_ITERATIONS`): chosen from
{0, 30, 100} in the first #33 run (commit 9d63a23; 30 and 100 alike) and fixed since."""
NORMAL_RADII = [0.0, 0.02, 0.03, 0.04, 0.05, 0.06]
"""Radii (m) of the reconstruction's plane-fit normals
(:func:`arlight.probeless.reconstruct.plane_fit_normals`; 0: the mesh's own normals)."""
DISTANCES = [0.1, 0.2, 0.3]
SETUP_RIDGES = [1e-4, 3e-4, 1e-3, 3e-3, 1e-2]
SETUP_VERSION = 2
"""Bump when a sequence's scores would change: 2 = E3 as unoccluded minus occluded
(:func:`arlight.probeless.transfer.compute_transfer`) and the normal-radius grid."""
LAMP_DOT_LOSS = 0.02
"""The near-lamp guard: a candidate (normal radius, range, ridge) is admissible only if on
every near-lamp training sequence its mean ``dot(d_est, d_lamp)`` is at most this below that
of :data:`GUARD_BASE`. A longer range helps under distant light and turns the estimate away
from a near lamp (bunny-box: dot 0.99 → 0.77 at 1 m; the lamp's shadows fall where no
distant direction puts them, docs/methods/probeless.md); 0.02 is the allowance the issue
gives bunny-box (~0.97 → ≥ 0.95). The first run of this rule compared each candidate with
10 cm *at the same ridge*, which let ridge 1e-4 pass at 0.3 m because at 10 cm that ridge had
already lost the lamp (dot 0.10): the baseline has been fixed constants since."""
GUARD_BASE = (0.0, 0.1, 1e-3)
"""(normal radius, range, ridge) the guard compares with: the constants of the first #33
choice (mesh normals, Gruber's 10 cm, ridge 1e-3), scored with today's transfer."""
SETUP_DEPTH = {"training": 8, "heldout": 2}
"""Mitsuba path depth of the frames: the training frames carry interreflection, as real
frames do (a transfer without interreflection must not be tuned on frames without it);
the held-out ones are Gruber's setup, direct light only (his renderings under an SH light)."""

Key = tuple[float, float, float]
"""(normal radius (m), visibility range (m), ridge)."""


def defaults() -> Key:
    """The package's current (normal radius, visibility range, ridge)."""
    from arlight.probeless.estimate import DEFAULT_RIDGE
    from arlight.probeless.reconstruct import NORMAL_RADIUS
    from arlight.probeless.transfer import MAX_DISTANCE

    return (NORMAL_RADIUS, MAX_DISTANCE, DEFAULT_RIDGE)


def setup_sequences(split: str) -> dict[str, tuple[str, Path | None]]:
    """Light setups (label -> (kind, HDR file)) of the ``training`` or ``heldout`` split;
    the training kind ``lamp`` is the near-lamp guard (not in the median)."""
    if split == "heldout":
        return {"Gruber SH cap light": ("sh", None)}
    pano = Path(__file__).resolve().parents[1] / "src/arlight/data/light/panoramas"
    return {"HDR studio_small_03": ("hdr", pano / "studio_small_03_512x256.hdr"),
            "HDR rooitou_park": ("hdr", pano / "rooitou_park_512x256.hdr"),
            "HDR lebombo": ("hdr", None),
            "near lamp": ("lamp", None)}


def setup_scores(kind: str, hdr: Path | None, moving: bool, max_depth: int, frames_n: int = 8
                 ) -> dict[Key, tuple[float, float]]:
    """Mean over frames of (upper-hemisphere error, dot) of ART4 per (normal radius,
    visibility range, ridge)."""
    from dataclasses import replace

    from arlight.backend.mitsuba_scene import build_views
    from arlight.probeless.estimate import estimate_light
    from arlight.probeless.experiment import upper_hemisphere_error
    from arlight.probeless.pipeline import Pipeline, Settings
    from arlight.probeless.reconstruct import plane_fit_normals, reconstruct
    from arlight.probeless.synthetic_rgbd import ALBEDO, render_sequence
    from arlight.scene.model import World

    frames = render_sequence(kind, n=frames_n, moving=moving, spp=64, hdr=hdr,
                             max_depth=max_depth)
    raw = reconstruct([f.rgbd for f in frames], albedo=ALBEDO, smooth_iterations=SMOOTHING,
                      normal_radius=0.0)
    out = {}
    for radius in NORMAL_RADII:
        normals = plane_fit_normals(raw.mesh.vertices, raw.mesh.normals, radius)
        mesh = replace(raw, mesh=replace(raw.mesh, normals=normals.astype(np.float32)))
        views = build_views(World(shapes=[mesh], lights=[]))
        for dist in DISTANCES:
            pipe = Pipeline(views, "ART4", Settings(max_distance=dist), shapes=[mesh])
            obs = [pipe.process(f.rgbd.camera, f.rgbd.colour, f.rgbd.depth,
                                shade=False).observations for f in frames]
            for ridge in SETUP_RIDGES:
                fits = [estimate_light(*o, ridge=ridge) for o in obs]
                out[(radius, dist, ridge)] = (
                    float(np.mean([upper_hemisphere_error(ft.sh, f.true_sh)
                                   for ft, f in zip(fits, frames, strict=True)])),
                    float(np.mean([ft.direction @ f.true_direction
                                   for ft, f in zip(fits, frames, strict=True)])))
    return out


def normal_scores(moving: bool, frames_n: int = 8) -> dict[str, dict[str, float]]:
    """Per normal radius: the angle (degrees) between the reconstruction's shading normal and
    the exact room's at every pixel both see (the training sequences' depth frames: the
    camera path of ``moving``, under ``studio_small_03``; depth does not depend on the
    light): mean, p50 and p90 over the frames' pixels."""
    from dataclasses import replace

    from arlight.backend.mitsuba_scene import build_views
    from arlight.probeless.pipeline import primary_hits
    from arlight.probeless.reconstruct import plane_fit_normals, reconstruct
    from arlight.probeless.synthetic_rgbd import ALBEDO, render_sequence, room_shapes
    from arlight.scene.model import World

    kind, hdr = setup_sequences("training")["HDR studio_small_03"]
    frames = render_sequence(kind, n=frames_n, moving=moving, spp=64, hdr=hdr,
                             max_depth=SETUP_DEPTH["training"])
    raw = reconstruct([f.rgbd for f in frames], albedo=ALBEDO, smooth_iterations=SMOOTHING,
                      normal_radius=0.0)
    exact = build_views(World(shapes=room_shapes(), lights=[]))
    truth = [primary_hits(exact, f.rgbd.camera, mixed=False) for f in frames]
    out = {}
    for radius in NORMAL_RADII:
        normals = plane_fit_normals(raw.mesh.vertices, raw.mesh.normals, radius)
        mesh = replace(raw, mesh=replace(raw.mesh, normals=normals.astype(np.float32)))
        views = build_views(World(shapes=[mesh], lights=[]))
        ang = []
        for f, ht in zip(frames, truth, strict=True):
            hr = primary_hits(views, f.rgbd.camera, mixed=False)
            ok = np.isfinite(ht.z) & np.isfinite(hr.z)
            cos = np.einsum("hwc,hwc->hw", ht.normal, hr.normal)[ok]
            ang.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        a = np.concatenate(ang)
        out[repr(radius)] = {"mean": float(a.mean()), "p50": float(np.median(a)),
                             "p90": float(np.percentile(a, 90))}
    return out


DECOMPOSE_ROWS = ("reconstruction, mesh normals", "reconstruction (defaults)",
                  "exact geometry", "exact geometry, visibility unlimited",
                  "exact geometry, visibility unlimited, 1024 directions",
                  "the same, observations = exact model (noise-free)",
                  "the same, ridge 1e-4")
"""The rows of :func:`decompose`, each replacing one more input by the truth."""


def decompose(kind: str, hdr: Path | None, moving: bool, max_depth: int, frames_n: int = 8
              ) -> dict[str, float]:
    """What limits the estimate: the mean upper-hemisphere error of ART4 at the package's
    defaults as inputs are replaced by the truth one after another (:data:`DECOMPOSE_ROWS`),
    plus two floors: the truth with band 3 zeroed (what a light seen only through unoccluded
    Lambertian transfer cannot recover: Â_3 = 0) and the relative residual of the *true*
    light in E5 with everything exact (noise and light beyond band 3 in the frames).
    The albedo is exact in every row (one known albedo, as the reconstruction assumes)."""
    from dataclasses import replace

    from arlight.backend.mitsuba_scene import build_views
    from arlight.probeless.directions import DirectionSet
    from arlight.probeless.estimate import estimate_light
    from arlight.probeless.experiment import upper_hemisphere_error
    from arlight.probeless.pipeline import Pipeline, Settings, Variant
    from arlight.probeless.reconstruct import reconstruct
    from arlight.probeless.synthetic_rgbd import ALBEDO, render_sequence, room_shapes
    from arlight.scene.model import World

    radius, dist, ridge = defaults()
    frames = render_sequence(kind, n=frames_n, moving=moving, spp=64, hdr=hdr,
                             max_depth=max_depth)
    rec = reconstruct([f.rgbd for f in frames], albedo=ALBEDO, normal_radius=radius)
    raw = reconstruct([f.rgbd for f in frames], albedo=ALBEDO, normal_radius=0.0)
    exact = build_views(World(shapes=room_shapes(), lights=[]))
    full = Variant("all rays", 4, False, 1, False)

    def observe(views, variant="ART4", d=dist, directions=None):
        pipe = Pipeline(views, variant, Settings(max_distance=d), directions=directions)
        return [pipe.process(f.rgbd.camera, f.rgbd.colour, f.rgbd.depth,
                             shade=False).observations for f in frames]

    def err(obs, r=ridge) -> float:
        return float(np.mean([upper_hemisphere_error(estimate_light(*o, ridge=r).sh, f.true_sh)
                              for o, f in zip(obs, frames, strict=True)]))

    dense = observe(exact, full, 100.0, DirectionSet(1024, 1))
    model = [(T, a / np.pi * (T @ f.true_sh), a) for (T, _, a), f in zip(dense, frames,
                                                                         strict=True)]
    rows = [err(observe(build_views(World(shapes=[raw], lights=[])))),
            err(observe(build_views(World(shapes=[rec], lights=[])))),
            err(observe(exact)), err(observe(exact, d=100.0)), err(dense), err(model),
            err(model, 1e-4)]
    out = dict(zip(DECOMPOSE_ROWS, rows, strict=True))
    band3 = [replace(f, true_sh=f.true_sh * (np.arange(16) < 9)[:, None]) for f in frames]
    out["floor: truth without band 3"] = float(np.mean(
        [upper_hemisphere_error(g.true_sh, f.true_sh) for g, f in zip(band3, frames,
                                                                       strict=True)]))
    out["residual of the true light, everything exact"] = float(np.mean(
        [np.sqrt(np.mean((a / np.pi * (T @ f.true_sh) - b) ** 2) / np.mean(b ** 2))
         for (T, b, a), f in zip(dense, frames, strict=True)]))
    return out


def decompose_section() -> str:
    """The decomposition table over the held-out and the distant-light training setups."""
    cols = {}
    for split in ("heldout", "training"):
        for label, (kind, hdr) in setup_sequences(split).items():
            if kind == "lamp":
                continue
            for moving in (False, True):
                name = f"{label}, {'moving' if moving else 'static'}"
                cols[name] = cached(
                    f"decompose{SETUP_VERSION}-{name}-{defaults()}".replace(" ", "_"),
                    lambda kind=kind, hdr=hdr, moving=moving, split=split: decompose(
                        kind, hdr, moving, SETUP_DEPTH[split]))
                print(f"decompose {name} done", file=sys.stderr, flush=True)
    r, d, q = defaults()
    lines = ["### What limits the estimate", "",
             f"Mean upper-hemisphere error over the 8 frames, ART4 at the defaults (normal "
             f"radius {r:g} m, {d:g} m, ridge {q:g}) unless the row says otherwise, as inputs "
             "are replaced by the truth one after another (`tune_light_estimation.py "
             "--part decompose`): the reconstruction's mesh normals (before #33's plane "
             "fit), the reconstruction (defaults), the exact room, unlimited visibility "
             "rays, 1024 directions all cast every frame, the observations replaced by the "
             "exact model's prediction of the true light, and a weaker ridge. The albedo is "
             "exact throughout (one known albedo). Floors: the true light with band 3 "
             "zeroed, and the relative residual of the true light in E5 with everything "
             "exact (render noise at 64 spp, light beyond band 3, interreflection).", "",
             "| row | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for row in [*DECOMPOSE_ROWS, "floor: truth without band 3",
                "residual of the true light, everything exact"]:
        lines.append(f"| {row} | " + " | ".join(f"{c[row]:.3f}" for c in cols.values())
                     + " |")
    return "\n".join(lines)


def admissible(lamp: dict[str, dict], key: Key) -> bool:
    """The near-lamp guard (:data:`LAMP_DOT_LOSS`) for ``key`` over the lamp sequences."""
    return all(v[key][1] >= v[GUARD_BASE][1] - LAMP_DOT_LOSS for v in lamp.values())


def cached_scores(name: str, make) -> dict[Key, tuple[float, float]]:
    """:func:`setup_scores` through the JSON cache (``name`` names the setup and the grid)."""
    rec = cached(name, lambda: {f"{k[0]!r}|{k[1]!r}|{k[2]!r}": v for k, v in make().items()})
    return {(float(a), float(b), float(c)): tuple(v)
            for k, v in rec.items() for a, b, c in [k.split("|")]}


def setups_section() -> str:
    """Choose (normal radius, range, ridge) on the distant-light training setups under the
    near-lamp guard; report both splits."""
    t0 = time.perf_counter()
    res: dict[str, dict[str, dict]] = {}
    grid = f"{NORMAL_RADII}{DISTANCES}{SETUP_RIDGES}".replace(" ", "")
    for split in ("training", "heldout"):
        res[split] = {}
        for label, (kind, hdr) in setup_sequences(split).items():
            for moving in (False, True):
                name = f"{label}, {'moving' if moving else 'static'}"
                res[split][name] = cached_scores(
                    f"setups{SETUP_VERSION}-{name}-{SETUP_DEPTH[split]}-{grid}".replace(" ", "_"),
                    lambda kind=kind, hdr=hdr, moving=moving, split=split: setup_scores(
                        kind, hdr, moving, SETUP_DEPTH[split]))
                print(f"setups {name} done", file=sys.stderr, flush=True)
    lamp = {n: v for n, v in res["training"].items() if n.startswith("near lamp")}
    distant = {n: v for n, v in res["training"].items() if n not in lamp}
    keys = [(q, d, r) for q in NORMAL_RADII for d in DISTANCES for r in SETUP_RIDGES]
    train_med = {k: float(np.median([v[k][0] for v in distant.values()])) for k in keys}
    geo = {cam: cached(f"normals{SETUP_VERSION}-{cam}-{NORMAL_RADII}".replace(" ", ""),
                       lambda cam=cam: normal_scores(cam == "moving"))
           for cam in ("static", "moving")}
    geo_mean = {q: float(np.mean([g[repr(q)]["mean"] for g in geo.values()]))
                for q in NORMAL_RADII}
    radius = min(NORMAL_RADII, key=lambda q: (round(geo_mean[q], 2), q))
    best = min((k for k in keys if k[0] == radius and admissible(lamp, k)),
               key=lambda k: (round(train_med[k], 4), k))
    alt = min((k for k in keys if admissible(lamp, k)),
              key=lambda k: (round(train_med[k], 4), k))
    lines = [SETUPS_HEADING, "",
             "`.venv/bin/python benchmarks/tune_light_estimation.py --part setups --write` — "
             "the modelled room of `bench_probeless.py` (8 frames, 160×120, 64 spp, TSDF 2 m "
             f"at 268³, {SMOOTHING} Taubin passes (chosen from {{0, 30, 100}} in the first "
             "#33 run, commit 9d63a23), vertex normals from a plane fit of the "
             "radius in the table (0: the mesh's own), ART4, E3 as unoccluded minus occluded); "
             "training: the room under three "
             "real HDR maps, static and moving camera (6 sequences), path traced with "
             "interreflection (depth 8), and under a near lamp (`synthetic_rgbd.near_lamp`: "
             "bunny-box's 25 cm lamp 0.9 m from the objects, moved around the room; static "
             "and moving; depth 8) as a guard; held-out: Gruber's animated SH cap light, "
             "static and moving, direct light only (depth 2, as his renderings). "
             "Upper-hemisphere error (RMS radiance error over upward directions / true RMS "
             "there; the near lamp's truth is the light arriving at the objects, "
             "`experiment.incident_sh`), mean over frames. Rule: the smallest median upper "
             "error over the 6 distant-light sequences among the candidates that keep the "
             f"near lamp's direction (mean dot at most {LAMP_DOT_LOSS:g} below that of "
             f"radius {GUARD_BASE[0]:g}, {GUARD_BASE[1]:g} m, ridge {GUARD_BASE[2]:g} on each "
             "lamp sequence, `LAMP_DOT_LOSS`). Per-sequence results are cached "
             "(`~/.cache/arlight/tune_light`).", "",
             "| normal radius (m) | max_distance (m) | ridge | training median upper error | "
             + " | ".join(f"near lamp {n.split(', ')[1]}: upper / dot" for n in lamp)
             + " | guard | "
             + " | ".join(f"held-out {n}: upper / dot" for n in res["heldout"]) + " |",
             "|---|---|---|---|" + "---|" * (len(lamp) + 1 + len(res["heldout"]))]
    for k in keys:
        mark = (" (chosen)" if k == best else " (defaults)" if k == defaults()
                else " (guard base)" if k == GUARD_BASE else "")
        lines.append(f"| {k[0]:g}{mark} | {k[1]:g} | {k[2]:g} | {train_med[k]:.3f} | "
                     + " | ".join(f"{v[k][0]:.3f} / {v[k][1]:.4f}" for v in lamp.values())
                     + f" | {'ok' if admissible(lamp, k) else 'fails'} | "
                     + " | ".join(f"{v[k][0]:.3f} / {v[k][1]:.4f}"
                                  for v in res["heldout"].values()) + " |")
    lines += ["", "**Normal radius** (chosen first, by geometry): mean angle (°) between the "
              "reconstruction's shading normal and the exact room's over the training "
              "sequences' pixels (the depth does not depend on the light), static / moving "
              "camera: " + "; ".join(
                  f"{q:g} m {geo['static'][repr(q)]['mean']:.2f} / "
                  f"{geo['moving'][repr(q)]['mean']:.2f}" for q in NORMAL_RADII)
              + f" → **{radius:g} m**; then the light rule at that radius. The light rule "
              f"over the radius as well would pick radius {alt[0]:g} m, {alt[1]:g} m, ridge "
              f"{alt[2]:g} (training median {train_med[alt]:.3f} vs {train_med[best]:.3f}; "
              "held out " + ", ".join(f"{v[alt][0]:.3f}" for v in res["heldout"].values())
              + "): the geometric criterion was adopted after the first run's table "
              "(radii up to 5 cm, light rule over the radius: radius 0) had been seen; "
              "docs/methods/probeless.md, *Plane-fit normals*."]
    lines += ["", "Per distant-light training sequence at the chosen constants (upper error "
              "/ dot): " + "; ".join(f"{n} {v[best][0]:.3f} / {v[best][1]:.4f}"
                                     for n, v in distant.items())
              + f". Training choice: **normal radius {best[0]:g} m, max_distance "
              f"{best[1]:g} m, ridge {best[2]:g}**; package defaults now "
              f"{defaults()[0]:g} m, {defaults()[1]:g} m, {defaults()[2]:g}. Load: `uptime` "
              f"{os.getloadavg()[0]:.2f} (1 min), CPU pressure (PSI some avg60) "
              f"{cpu_pressure() or 'n/a'} %; run {time.perf_counter() - t0:.0f} s."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", type=int, default=12)
    ap.add_argument("--heldout", type=int, default=24)
    ap.add_argument("--rooms-train", type=int, default=5)
    ap.add_argument("--rooms-heldout", type=int, default=0)
    ap.add_argument("--nearfield-heldout", default="",
                    help="explicit held-out seeds for nearfield (e.g. 1000001,1000004) "
                         "instead of the first --heldout plus --rooms-heldout")
    ap.add_argument("--part", choices=("probeless", "nearfield", "setups", "decompose",
                                       "all"),
                    default="all")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    if args.part == "decompose":  # printed only: RESULTS gets it with --part setups
        print(decompose_section())
        return
    if args.part == "setups":
        publish(setups_section() + "\n\n" + decompose_section(), args.write)
        return
    t0 = time.perf_counter()
    text = [HEADING, ""]
    parts: list[str] = []
    chosen = {}
    if args.part in ("probeless", "all"):
        recs: dict[str, list[dict]] = {"training": [], "heldout": []}
        for split, n in (("training", args.train), ("heldout", args.heldout)):
            for s in split_seeds(split, n):
                recs[split].append(cached(f"probeless-{s}", lambda s=s: probeless_world(s)))
                print(f"probeless light {s} done", file=sys.stderr, flush=True)
        keys = [repr(r) for r in RIDGES]
        ridge = choose(light_rows(recs["training"]), keys,
                       lambda r, k: r["light"][k]["sh_error"], repr(OLD_RIDGE), False)[0]
        for r in recs["training"] + recs["heldout"]:  # the composite of old and new
            with_composites(f"probeless-{r['seed']}", r, [repr(OLD_RIDGE), ridge],
                            lambda s=r["seed"]: probeless_composite(s))
            print(f"probeless composite {r['seed']} done", file=sys.stderr, flush=True)
        sec, chosen["ridge"] = probeless_section(recs["training"], recs["heldout"])
        parts += [sec, probeless_distribution(recs["heldout"], OLD_RIDGE)]
        if chosen["ridge"] != OLD_RIDGE:
            parts.append(probeless_distribution(recs["heldout"], chosen["ridge"]))
    if args.part in ("nearfield", "all"):
        recs = {}
        for split, n, rooms in (("training", args.train, args.rooms_train),
                                ("heldout", args.heldout, args.rooms_heldout)):
            recs[split] = []
            seeds = (parse_worlds(args.nearfield_heldout)
                     if split == "heldout" and args.nearfield_heldout
                     else nearfield_seeds(split, n, rooms))
            for s in seeds:
                recs[split].append(cached(f"nearfield-{s}", lambda s=s: nearfield_world(s)))
                print(f"nearfield {s} done", file=sys.stderr, flush=True)
        sec, chosen["tau"] = nearfield_section(recs["training"], recs["heldout"])
        parts.append(sec)
    text.append(
        f"Worlds: generator v{GENERATOR_VERSION}, {WIDTH}×{WIDTH * 3 // 4}, ground truth "
        f"{GT['spp']} spp (seed {GT['seed']}, depth {GT['max_depth']}); training seeds from "
        f"0, held-out from 1000000 (first {args.train} / {args.heldout}). Training choices: "
        + ", ".join(f"{k} = {v:g}" for k, v in chosen.items())
        + "; defaults kept at ridge = 0.003, τ = 0.6 (below)"
        + f". CPU pressure (PSI some avg60) at the end: {cpu_pressure() or 'n/a'} %; "
        f"this run {time.perf_counter() - t0:.0f} s (per-world results cached). Run: "
        "`.venv/bin/python benchmarks/tune_light_estimation.py --write`.")
    text += ["", NOTE]
    publish("\n\n".join(["\n".join(text), *parts]), args.write)


if __name__ == "__main__":
    main()
