"""arlight studio under load and in a browser (issue #20).

Two parts, both against a studio served on a loopback port by this process:

* **load** — ``--clients`` (8) concurrent WebSocket clients each pick the bunny and drag it
  to random pixels of the demo scene (a drag message every 1/``--rate`` s) for ``--seconds``
  (60): error messages (must be 0), frames and frame rate per client, the frames the
  server dropped or superseded (latest-wins), and this process's RSS after the warm-up and
  at the end (server and clients share the process; flat = no leak per frame).
* **latency** — headless Chromium (Playwright, Debian's chromium) on the page at
  ``--latency-resolution`` (640×480): per interactive method, a real pointer drag of the
  object; the time from the pointer event to the new composite drawn on the canvas
  (``performance.now()`` in the page), against the server's render time of that frame.
  Methods are interleaved over ``--rounds`` rounds; medians reported.

    .venv/bin/python benchmarks/bench_studio.py [--write] [--only load|latency]

* **video rate** (issue #32, ``--only video``) — the same page at 640×480 with adaptive
  resolution: per method, ``--drags`` (12) continuous pointer drags (``--moves`` pointer
  events ``--move-ms`` apart each), every frame shown during a drag timed from the pointer
  event it shows to its draw on the canvas (p50, p95), the scale factors used, and the time
  from the last pointer event (the pointer rests) to the full-size frame drawn; then the
  render time per scale of each method with the object moving (what an unloaded machine
  would scale), and the machine's load (``uptime``, CPU pressure) before and after.

``--write`` stores the sections in RESULTS.md (## arlight studio; ## Studio at video rate).
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import os
import random
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.results import cpu_pressure, publish  # noqa: E402

HEADING = "## arlight studio (issue #20)"
VIDEO_HEADING = "## Studio at video rate (issue #32)"
VIDEO_METHODS = ("dlpv", "dir", "dvct", "ibl", "prt")
"""The methods of issue #32's acceptance."""


def _engine(resolution: tuple[int, int], method: str = "dir", **config):
    from arlight.demo import demo_scene_path
    from arlight.studio import Engine, StudioConfig

    return Engine(StudioConfig(demo_scene_path(), resolution=resolution, method=method,
                               **config))


# ---------------------------------------------------------------------- load
async def _client(ws_url: str, seconds: float, rate: float, seed: int, engine) -> dict:
    import aiohttp

    from arlight.studio.protocol import split_frame

    rng = random.Random(seed)
    w, h = engine.width, engine.height
    out = {"frames": 0, "errors": [], "first_frame_s": None, "superseded": 0}
    async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url) as ws:
        t0 = time.perf_counter()
        stop = t0 + seconds

        async def reader():
            async for m in ws:
                if m.type == aiohttp.WSMsgType.BINARY:
                    head, _ = split_frame(m.data)
                    out["frames"] += 1
                    out["superseded"] += bool(head["superseded"])
                    if out["first_frame_s"] is None:
                        out["first_frame_s"] = time.perf_counter() - t0
                elif m.type == aiohttp.WSMsgType.TEXT:
                    msg = json.loads(m.data)
                    if msg["type"] == "error":
                        out["errors"].append(msg["message"])
                else:
                    break

        task = asyncio.create_task(reader())
        rest = engine.rest_poses["bunny"]
        head = engine.proxy.project(rest.position + [0.0, 0.04, 0.0])
        await ws.send_json({"type": "pick", "x": head[0], "y": head[1]})
        seq = 0
        while time.perf_counter() < stop:
            seq += 1
            x, y = rng.uniform(0.1 * w, 0.9 * w), rng.uniform(0.55 * h, 0.98 * h)
            if rng.random() < 0.05:  # now and then a rotation or a scale
                await ws.send_json({"type": "pose", "object": "bunny", "seq": seq,
                                    "yaw_deg": rng.uniform(-180, 180),
                                    "scale": rng.uniform(0.7, 1.4)})
            else:
                await ws.send_json({"type": "drag", "x": x, "y": y, "seq": seq})
            await asyncio.sleep(1.0 / rate)
        out["seconds"] = time.perf_counter() - t0
        out["sent"] = seq
        await ws.close()
        await asyncio.gather(task, return_exceptions=True)
    return out


def run_load(clients: int, seconds: float, rate: float, resolution: tuple[int, int]) -> dict:
    from arlight.studio.server import BackgroundServer

    engine = _engine(resolution)
    proc = psutil.Process()
    with BackgroundServer(engine) as srv:
        async def warm():  # every method state and kernel the load uses, compiled
            await _client(srv.ws_url, 3.0, 5.0, 0, engine)

        asyncio.run(warm())
        rss0 = proc.memory_info().rss

        async def main():
            return await asyncio.gather(*[_client(srv.ws_url, seconds, rate, 1 + i, engine)
                                          for i in range(clients)])

        samples: list[tuple[float, float]] = []
        done = threading.Event()

        def sample():  # RSS every 2 s during the load
            t0 = time.perf_counter()
            while not done.wait(2.0):
                samples.append((time.perf_counter() - t0, proc.memory_info().rss / 2**20))

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        results = asyncio.run(main())
        done.set()
        sampler.join()
        rss1 = proc.memory_info().rss
        alive = bool(engine._thread and engine._thread.is_alive())
    fps = [r["frames"] / r["seconds"] for r in results]
    return {"clients": clients, "seconds": seconds, "rate": rate, "resolution": resolution,
            "fps": fps, "frames": [r["frames"] for r in results],
            "sent": [r["sent"] for r in results],
            "superseded": sum(r["superseded"] for r in results),
            "errors": [e for r in results for e in r["errors"]],
            "first_frame_s": [r["first_frame_s"] for r in results],
            "rss_mb": (rss0 / 2**20, rss1 / 2**20), "rss_samples": samples,
            "worker_alive": alive}


# ---------------------------------------------------------------------- latency
FAST_METHODS = ("dir", "dlpv", "dvct", "ibl", "prt", "onepass")
"""The latency benchmark's default methods: the issue's fast ones and progressive onepass."""


def run_latency(rounds: int, resolution: tuple[int, int],
                methods: tuple[str, ...] | None = FAST_METHODS) -> dict:
    from playwright.sync_api import sync_playwright

    from arlight.studio.browser import why_no_browser
    from arlight.studio.server import BackgroundServer

    if (why := why_no_browser()) is not None:
        raise SystemExit(f"latency benchmark: {why}")
    engine = _engine(resolution)
    names = [n for n, i in engine.catalogue.items() if not i.unsupported
             and (methods is None or n in methods)]
    lat: dict[str, list[float]] = {n: [] for n in names}
    render: dict[str, list[float]] = {n: [] for n in names}
    rng = random.Random(0)
    with BackgroundServer(engine) as srv, sync_playwright() as p:
        browser, page, box = _open_page(p, srv.url, 1100, 640)
        for d in _browser_drags(page, box, engine, names, rounds, rng):
            rec = d["records"][-1]
            lat[d["method"]].append(rec["ms"] / 1e3)
            render[d["method"]].append(rec["render_s"])
        browser.close()
    return {"rounds": rounds, "resolution": resolution, "latency": lat, "render": render}


def _browser_drags(page, box: dict, engine, names: list[str], rounds: int,
                   rng: random.Random, moves: int = 1, move_ms: float = 0.0,
                   to_rest: bool = False):
    """Drag the bunny on the studio ``page`` (the frame image at ``box``): ``rounds`` + 1
    rounds over ``names`` (round 0 warms up: preparation, kernel compilation), each drag
    from the bunny to a random point on the table in ``moves`` pointer events ``move_ms``
    apart. The drag ends when the page has drawn a frame of its last event — with
    ``to_rest``, the full-size frame after the pointer rests. Yields per measured drag
    ``{"method", "records"}`` (the page's latency records of the drag), ``"last"`` (the
    last event sent: seq, time) and ``"log"`` (the page's log of frames shown)."""
    w, h = engine.width, engine.height

    def client(x, y):
        return box["x"] + x / w * box["width"], box["y"] + y / h * box["height"]

    full = (" && window.studio.header.factor === 1 && !window.studio.header.preview"
            if to_rest else "")
    for r in range(rounds + 1):
        for name in names:
            page.select_option("#method", name)
            page.wait_for_function(f"window.studio.header.method === '{name}' && "
                                   f"window.studio.sendTimes.size === 0{full}",
                                   timeout=900_000)
            pos = page.evaluate("window.studio.header.objects.bunny.position")
            start = engine.proxy.project(np.array(pos) + [0.0, 0.03, 0.0])
            target = (rng.uniform(0.25 * w, 0.75 * w), rng.uniform(0.65 * h, 0.9 * h))
            page.mouse.move(*client(*start))
            page.mouse.down()
            page.wait_for_function("window.studio.messages.some(m => m.type === "
                                   "'picked' && m.object)", timeout=60_000)
            page.evaluate("window.studio.messages = []")
            n0 = page.evaluate("window.studio.latencies.length")
            for t in np.linspace(0.0, 1.0, moves + 1)[1:]:
                page.mouse.move(*client(start[0] + t * (target[0] - start[0]),
                                        start[1] + t * (target[1] - start[1])))
                if move_ms:
                    page.wait_for_timeout(move_ms)
            last = page.evaluate("window.studio.lastSent")
            if to_rest:  # the antialiased full-size frame (after a one-sample preview)
                page.wait_for_function(
                    f"window.studio.shownLog.some(f => f.seq >= {last['seq']} && "
                    "f.factor === 1 && !f.preview)", timeout=900_000)
            else:
                page.wait_for_function(f"window.studio.latencies.length > {n0}",
                                       timeout=900_000)
            page.mouse.up()
            if r == 0:
                continue
            yield {"method": name, "records": page.evaluate(
                f"window.studio.latencies.slice({n0})"), "last": last,
                "log": page.evaluate("window.studio.shownLog") if to_rest else []}


def _percentile(xs: list[float], q: float) -> float:
    """The ``q``-th percentile (0–100) of ``xs``, linear interpolation; NaN when empty."""
    return float(np.percentile(xs, q)) if xs else float("nan")


def _load() -> dict:
    """The machine's load now: 1/5/15-minute load averages, CPU pressure (avg60, %)."""
    import os

    return {"loadavg": os.getloadavg(), "cpu_pressure": cpu_pressure(),
            "cpus": os.cpu_count()}


def _scale_times(engine, names: list[str], reps: int) -> dict[str, dict]:
    """Median ``method.render`` time (s) per method and downscale factor with the object
    moving 2 cm along the table every frame, and the median of its ``time_pose`` stage (on
    the render worker, after the page's frames)."""
    from dataclasses import replace

    from arlight.methods import get_method
    from arlight.studio.engine import _transforms

    def measure(name: str) -> dict:
        fn = get_method(name)
        engine.prepared(name)
        drag = engine._drag[name]  # each size's state and settings (drag options)
        rest = engine.rest_poses["bunny"]
        out: dict = {"pose": []}
        step = 0
        for k in engine.factors:
            ts = []
            for i in range(reps + 1):  # the first one warms up
                step += 1
                pose = rest.moved_to(rest.position + [0.02 * (step % 8) - 0.08, 0.0,
                                                      0.01 * (step % 3)])
                view = replace(engine.views[k], object_transforms=_transforms(
                    {"bunny": pose}))
                engine._set_jit_threads(k > 1)  # workers and calls as the studio renders that size
                t0 = time.perf_counter()
                layers = fn.render(drag.state(k), view, drag.settings(k))
                ts.append(time.perf_counter() - t0)
                if i:
                    out["pose"].append(layers.stats.get("time_pose", float("nan")))
            out[k] = statistics.median(ts[1:])
        out["pose"] = statistics.median(out["pose"])
        return out

    return {n: engine.call(measure, n).result(3600) for n in names}


def run_video(drags: int, moves: int, move_ms: float, resolution: tuple[int, int],
              methods: tuple[str, ...], reps: int, drag_threads: int = 1,
              drag_calls: str = "evaluated") -> dict:
    """Continuous drags in Chromium with adaptive resolution (see the module doc)."""
    from playwright.sync_api import sync_playwright

    from arlight.studio.browser import why_no_browser
    from arlight.studio.server import BackgroundServer

    if (why := why_no_browser()) is not None:
        raise SystemExit(f"video-rate benchmark: {why}")
    load0 = _load()
    engine = _engine(resolution, drag_threads=drag_threads, drag_calls=drag_calls)
    names = [n for n in methods if n in engine.catalogue
             and not engine.catalogue[n].unsupported]
    lat = {n: [] for n in names}  # (ms, factor) per frame shown while dragging
    first = {n: [] for n in names}  # the first frame of each drag, ms
    settle = {n: [] for n in names}  # last pointer event -> full-size frame drawn, ms
    final = {n: [] for n in names}  # ... -> the antialiased full-size frame (after a preview)
    renders = {n: [] for n in names}  # (factor, render_s, pose_s) of the frames shown
    stages = {n: [] for n in names}  # the server's stage times (s) of the frames shown
    log_drags: list[dict] = []  # per drag: its last seq, (seq, factor, ms) of its frames
    rng = random.Random(1)
    with BackgroundServer(engine) as srv, sync_playwright() as p:
        browser, page, box = _open_page(p, srv.url, 1100, 640)
        for d in _browser_drags(page, box, engine, names, drags, rng, moves, move_ms,
                                to_rest=True):
            name, last, log = d["method"], d["last"], d["log"]
            full = [f for f in log if f["seq"] is not None and f["seq"] >= last["seq"]
                    and f["factor"] == 1]
            settle[name].append(min(f["at"] for f in full) - last["t"])
            final[name].append(min(f["at"] for f in full if not f.get("preview"))
                               - last["t"])
            drag = [x for x in d["records"] if x["type"] == "drag"]
            log_drags.append({"method": name, "last": last["seq"], "frames": [
                (x["seq"], x["factor"], round(x["ms"])) for x in drag]})
            lat[name] += [(x["ms"], x["factor"]) for x in drag]
            renders[name] += [(x["factor"], x["render_s"], x.get("pose_s")) for x in drag]
            stages[name] += [{**x.get("stats", {}), "server_ms": x.get("server_ms"),
                              "ms": x["ms"]} for x in drag]
            if drag:
                first[name].append(drag[0]["ms"])
        browser.close()
        load1 = _load()
        per_scale = _scale_times(engine, names, reps)
    return {"drags": drags, "moves": moves, "move_ms": move_ms, "resolution": resolution,
            "budget_ms": engine.config.frame_budget_ms, "rest_ms": engine.config.rest_ms,
            "factors": engine.factors, "latency": lat, "first": first, "settle": settle,
            "final": final,
            "renders": renders, "per_scale": per_scale, "load": [load0, load1],
            "stages": stages, "drag_threads": drag_threads, "drag_calls": drag_calls,
            "openblas": os.environ.get("OPENBLAS_NUM_THREADS"),
            "drag_log": log_drags}


def _drag_extra(name: str, factor: int) -> dict:
    """The options ``name``'s spec overrides on a drag frame at ``factor``."""
    from arlight.methods import get_method

    spec = get_method(name).spec
    return spec.drag(spec.parse_options({}), factor)


def video_report(v: dict) -> str:
    """The ``## Studio at video rate`` section of RESULTS.md."""
    w, h = v["resolution"]
    loads = "; ".join(f"{when}: load average {a:.1f} / {b:.1f} / {c:.1f} (1/5/15 min) on "
                      f"{x['cpus']} CPUs, CPU pressure (avg60) {x['cpu_pressure'] or 'n/a'} %"
                      for when, x in zip(("before", "after the drags"), v["load"],
                                         strict=True) for a, b, c in [x["loadavg"]])
    env = f"OPENBLAS_NUM_THREADS={v['openblas']} " if v.get("openblas") else ""
    lines = [VIDEO_HEADING, "",
             f"`{env}benchmarks/bench_studio.py --only video --drag-threads "
             f"{v.get('drag_threads', 1)} --drag-calls {v.get('drag_calls', 'symbolic')}`: "
             f"the studio at {w}×{h} in headless "
             f"Chromium with adaptive resolution (render budget {v['budget_ms']:.0f} ms, rest "
             f"after {v['rest_ms']:.0f} ms; factors {', '.join(map(str, v['factors']))}); per "
             f"method {v['drags']} drags of {v['moves']} pointer events {v['move_ms']:.0f} ms "
             "apart (methods interleaved, after a warm-up round). *drag → composite*: every "
             "frame drawn during a drag, from the pointer event it shows to its draw on the "
             "canvas. *rest → full size*: from the last pointer event to the full-size frame "
             "drawn (includes the rest interval); *antialiased*: to the full-size frame with "
             "the method's G-buffer samples, after a one-sample preview where it takes "
             "several (dir, dlpv, dvct: `DragStates.preview`). Machine load — " + loads + ".",
             "",
             "| method | frames | drag → composite p50 (ms) | p95 (ms) | first frame of a "
             "drag p50 (ms) | factors used (share of frames) | rest → full size p50 / max "
             "(ms) | rest → antialiased p50 / max (ms) |", "|---|---|---|---|---|---|---|---|"]
    for name, xs in v["latency"].items():
        ms = [m for m, _ in xs]
        used = collections.Counter(k for _, k in xs)
        share = ", ".join(f"1/{k}: {c / max(len(xs), 1):.0%}" if k > 1 else
                          f"full: {c / max(len(xs), 1):.0%}" for k, c in sorted(used.items()))
        st, fin = v["settle"][name], v.get("final", {}).get(name, [])
        lines.append(f"| {name} | {len(ms)} | {_percentile(ms, 50):.0f} | "
                     f"{_percentile(ms, 95):.0f} | {_percentile(v['first'][name], 50):.0f} | "
                     f"{share} | {_percentile(st, 50):.0f} / "
                     f"{max(st) if st else float('nan'):.0f} | {_percentile(fin, 50):.0f} / "
                     f"{max(fin) if fin else float('nan'):.0f} |")
    facs = v["factors"]
    lines += ["", "Options of the drag frames (each method's `drag_options`, issue #32: "
              "per-frame work that does not shrink with the image scaled too; full size at "
              "rest uses the defaults): " + "; ".join(
                  f"{name} " + ", ".join(f"1/{k}: " + " ".join(
                      f"{o}={x}" for o, x in _drag_extra(name, k).items()) for k in facs[1:])
                  for name in v["latency"] if any(_drag_extra(name, k) for k in facs[1:]))
              + "."]
    lines += ["", "Render time of the drag frames drawn (server `method.render`, pose "
              "included), median per size, ms (frames), and the median `pose` stage:", "",
              "| method | " + " | ".join(f"{w // k}×{h // k}" for k in facs)
              + " | pose |", "|---|" + "---|" * (len(facs) + 1)]
    for name, recs in v["renders"].items():
        cells = []
        for k in facs:
            ts = [r[1] for r in recs if r[0] == k]
            cells.append(f"{statistics.median(ts) * 1e3:.0f} ({len(ts)})" if ts else "–")
        poses = [r[2] for r in recs if r[2] is not None]
        cells.append(f"{statistics.median(poses) * 1e3:.0f}" if poses else "–")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "Where a drag frame's time goes (issue #32; medians over the frames drawn, "
              "ms): *wait* — from the change it shows to the start of its render (the worker "
              "busy with the previous frame; latest wins, so never a queue of stale ones); "
              "*place* — standing the object on the surface under the pointer; "
              "*render* (`method.render`); *upsample* — full size in the insertion's "
              "footprint only (*window*: its share of the frame); *display* — the camera "
              "transfer in that window over the photo's codes; *JPEG*; *server* — the "
              "change to the frame posted; *page* — the rest of *drag → composite* (the "
              "pointer event reaching the server, the WebSocket, decoding and drawing):", "",
              "| method | wait | place | render | upsample | window | display | JPEG | server "
              "| page |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, recs in v.get("stages", {}).items():
        def med(key: str, scale: float = 1e3, recs=recs) -> str:
            xs = [r[key] for r in recs if r.get(key) is not None]
            return f"{statistics.median(xs) * scale:.0f}" if xs else "–"

        page = [r["ms"] - r["server_ms"] for r in recs if r.get("server_ms") is not None]
        page_ms = f"{statistics.median(page):.0f}" if page else "–"
        lines.append(f"| {name} | {med('wait_s')} | {med('time_place')} | {med('render_s')} | "
                     f"{med('upsample_s')} | {med('footprint', 100)} % | {med('display_s')} | "
                     f"{med('jpeg_s')} | {med('server_ms', 1)} | {page_ms} |")
    lines += ["", "`method.render` time per size with the object moving 2 cm along the table "
              "every frame (median of 3 after a warm-up, same process, measured right after "
              "the drags; the smaller sizes with the drag frames' Dr.Jit workers), ms — "
              "what shrinks with the pixel count, and the fixed per-frame cost (pose, "
              "light injection and propagation, voxelisation) that does not:", "",
              "| method | " + " | ".join(f"{w // k}×{h // k}" for k in facs)
              + " | pose |", "|---|" + "---|" * (len(facs) + 1)]
    for name, per in v["per_scale"].items():
        lines.append(f"| {name} | " + " | ".join(f"{per[k] * 1e3:.0f}" for k in facs)
                     + f" | {per['pose'] * 1e3:.0f} |")
    return "\n".join(lines)


def _open_page(p, url: str, width: int, height: int):
    """A browser showing the studio at ``url`` after its first frame: ``(browser, page,
    bounding box of the frame image)``."""
    from arlight.studio.browser import launch

    browser = launch(p)
    page = browser.new_page(viewport={"width": width, "height": height})
    page.goto(url)
    page.wait_for_function("window.studio.frames >= 1", timeout=300_000)
    return browser, page, page.locator("#frame").bounding_box()


# ---------------------------------------------------------------------- screenshot
def screenshot(path: Path, method: str = "dir") -> Path:
    """The page at 640×480 after dragging the bunny toward the camera (docs/images)."""
    from playwright.sync_api import sync_playwright

    from arlight.studio.server import BackgroundServer

    engine = _engine((640, 480), method)
    with BackgroundServer(engine) as srv, sync_playwright() as p:
        browser, page, box = _open_page(p, srv.url, 1030, 610)
        rest = engine.rest_poses["bunny"]
        start = engine.proxy.project(rest.position + [0.0, 0.05, 0.0])
        page.mouse.move(box["x"] + start[0], box["y"] + start[1])
        page.mouse.down()
        for t in np.linspace(0, 1, 6)[1:]:
            page.mouse.move(box["x"] + start[0] - 60 * t, box["y"] + start[1] + 40 * t)
        page.mouse.up()
        last = page.evaluate("window.studio.seq")
        page.wait_for_function(f"window.studio.header.seq >= {last} && "
                               "!window.studio.header.superseded", timeout=300_000)
        page.wait_for_timeout(500)
        page.screenshot(path=str(path))
        browser.close()
    return path


# ---------------------------------------------------------------------- report
def _half_slope(load: dict) -> float:
    """Least-squares RSS slope over the second half of the load run, MB per minute."""
    pts = [(t, m) for t, m in load["rss_samples"] if t >= load["seconds"] / 2]
    if len(pts) < 2:
        return float("nan")
    t, m = np.array(pts).T
    return float(np.polyfit(t, m, 1)[0] * 60.0)


def report(load: dict | None, latency: dict | None) -> str:
    lines = [HEADING, "",
             "`benchmarks/bench_studio.py`: the studio served on loopback by the benchmark "
             "process (bundled demo scene, method `dir` for the load test); one render "
             "worker thread for all clients, latest-wins. 2-core shared machine, CPU pressure "
             f"(avg60) {cpu_pressure() or 'n/a'} % at the end.", ""]
    if load:
        fps = load["fps"]
        r0, r1 = load["rss_mb"]
        lines += [f"**Load**: {load['clients']} WebSocket clients × {load['seconds']:.0f} s of "
                  f"random drags ({load['rate']:.0f} messages/s each, 5 % rotations/scales), "
                  f"{load['resolution'][0]}×{load['resolution'][1]}:", "",
                  "| | value |", "|---|---|",
                  f"| error messages | {len(load['errors'])} |",
                  f"| messages sent / frames received (all clients) | {sum(load['sent'])} / "
                  f"{sum(load['frames'])} |",
                  f"| frames per second per client: median (min–max) | "
                  f"{statistics.median(fps):.2f} ({min(fps):.2f}–{max(fps):.2f}) |",
                  f"| all clients together | {sum(fps):.1f} frames/s |",
                  f"| frames shown although superseded (finished after a newer drag) | "
                  f"{load['superseded']} |",
                  f"| RSS after warm-up → end | {r0:.0f} MB → {r1:.0f} MB "
                  f"({r1 - r0:+.0f} MB) |",
                  f"| RSS growth over the second half of the run | {_half_slope(load):+.1f} "
                  "MB/min |",
                  f"| render worker alive at the end | {load['worker_alive']} |", ""]
        if load["errors"]:
            lines += ["Errors: " + "; ".join(sorted(set(load["errors"]))[:5]), ""]
    if latency:
        lines += [f"**Latency** from a pointer drag on the page (headless Chromium) to the new "
                  f"composite drawn on its canvas, "
                  f"{latency['resolution'][0]}×{latency['resolution'][1]}, median of "
                  f"{latency['rounds']} drags per method (methods interleaved, after a "
                  "warm-up round); *render* is the server's `method.render` time of that "
                  "frame, the rest is picking the surface, tone mapping, JPEG, transport and "
                  "decoding:", "",
                  "| method | drag → composite (s) | render (s) | overhead (s) |",
                  "|---|---|---|---|"]
        for name, xs in latency["latency"].items():
            if not xs:
                continue
            m, rr = statistics.median(xs), statistics.median(latency["render"][name])
            lines.append(f"| {name} | {m:.3f} | {rr:.3f} | {m - rr:.3f} |")
        lines += ["", "A progressive method's row is its first (1 spp) frame after the drag; "
                  "it then refines while the pointer rests."]
    return "\n".join(lines)


def _size(text: str) -> tuple[int, int]:
    w, h = text.lower().split("x")
    return int(w), int(h)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("load", "latency", "video"))
    ap.add_argument("--screenshot", type=Path, help="only save a screenshot of the page "
                    "(docs/images/studio.png) and exit")
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=20.0, help="drag messages per second")
    ap.add_argument("--resolution", type=_size, default=(160, 120), help="load test size")
    ap.add_argument("--latency-resolution", type=_size, default=(640, 480))
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--methods", default=",".join(FAST_METHODS),
                    help="latency: comma-separated methods, or 'all' interactive ones")
    ap.add_argument("--drags", type=int, default=12, help="video: drags per method")
    ap.add_argument("--moves", type=int, default=20, help="video: pointer events per drag")
    ap.add_argument("--move-ms", type=float, default=33.0,
                    help="video: milliseconds between pointer events")
    ap.add_argument("--video-methods", default=",".join(VIDEO_METHODS))
    ap.add_argument("--drag-threads", type=int, default=1,
                    help="video: the studio's --drag-threads (Dr.Jit workers of drag frames)")
    ap.add_argument("--drag-calls", default="evaluated", choices=("evaluated", "symbolic"),
                    help="video: the studio's --drag-calls (Dr.Jit calls of drag frames)")
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    args = ap.parse_args()
    if args.screenshot:
        print(screenshot(args.screenshot))
        return
    if args.only == "video":
        video = run_video(args.drags, args.moves, args.move_ms, args.latency_resolution,
                          tuple(args.video_methods.split(",")), reps=3,
                          drag_threads=args.drag_threads, drag_calls=args.drag_calls)
        print(json.dumps(video, default=str))
        publish(video_report(video), args.write)
        return
    load = latency = None
    if args.only in (None, "load"):
        load = run_load(args.clients, args.seconds, args.rate, args.resolution)
        print(json.dumps({k: v for k, v in load.items() if k != "errors"}, default=str))
    if args.only in (None, "latency"):
        methods = None if args.methods == "all" else tuple(args.methods.split(","))
        latency = run_latency(args.rounds, args.latency_resolution, methods)
        print(json.dumps(latency))
    publish(report(load, latency), args.write)
    if load and (load["errors"] or not load["worker_alive"]):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
