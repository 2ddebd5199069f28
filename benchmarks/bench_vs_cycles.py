"""Peer benchmark: onepass (and reference) against Blender Cycles' shadow catcher (issue #22).

The same AR scene — the suite's ``bunny-box`` proxy: real diffuse table and open box, virtual
diffuse bunny and box, one rectangular area light and a constant environment — is rendered
by arlight and by Blender 5.0 Cycles (``bpy``, CPU, no denoiser, no adaptive sampling, box
pixel filter, the same bounce limit: Mitsuba's ``max_depth`` − 2 bounces) with the real
shapes as shadow catchers. Cycles' composite is the one its manual prescribes: the frame times
the *Shadow Catcher* pass, with the *Combined* pass (virtual objects, premultiplied alpha)
over it; arlight's is Debevec's differential composite (Eq. 2.20). Both composite the same
synthetic camera frame (Mitsuba's render of the world).

Measured, in one process with interleaved repeats (the machine is shared): for each
renderer and ``spp`` in ``--spp``, ``--repeats`` independent renders (different seeds) and
their wall times (arlight: the whole method call, scene preparation included; Cycles: its
synchronisation + render time from the EXR metadata). The *noise* of one render is its
relative RMSE about its own expectation, estimated from the repeats without any converged
image: ``sqrt(mean_pixels s²) / rms(c)``, with ``s²`` the per-pixel unbiased variance over the
repeats and ``c`` the mean of the renderer's highest-spp renders (a converged image of finite
spp would add its own noise to every error and flatten the curves near 1 %). A least-squares
line through log noise against log time gives the time to reach 5 %, 2.5 % and 1 %.
Correctness: the mean of each renderer's highest-spp renders against the ground-truth
photograph (Mitsuba, the world with the virtual objects), next to that mean's own noise.

bpy runs in its own virtual environment (bpy 5.0 requires numpy < 2; arlight needs numpy 2):

    python3.11 -m venv /tmp/venv-bpy && /tmp/venv-bpy/bin/pip install "bpy==5.0.*" "numpy<2"
    python benchmarks/bench_vs_cycles.py --bpy-python /tmp/venv-bpy/bin/python --write
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from results import cpu_pressure, publish

HEADING = "## Peer benchmark: onepass vs Blender Cycles at equal noise (issue 22)"
HERE = Path(__file__).resolve().parent
TARGETS = (0.05, 0.025, 0.01)
ARLIGHT = {  # label -> (method, options)
    "onepass": ("onepass", {"reproject": False}),
    "onepass scrambles": ("onepass", {"reproject": False, "replica_mode": "scrambles"}),
    "onepass before #22": ("onepass", {"reproject": False, "sampler": "independent",
                                       "replicas": 1, "light_sampling": "mitsuba"}),
    "reference": ("reference", {}),
}


def export_scene(scene, path: Path, max_depth: int) -> None:
    """The proxy's triangles, materials, lights and camera as an ``.npz`` for the worker."""
    import mitsuba as mi

    from arlight.backend.mitsuba_scene import describe_views, virtual_names

    objs = describe_views(scene)["mixed"]["objects"]
    virtual = virtual_names(scene)
    out: dict[str, np.ndarray] = {}
    n = 0
    for name, node in objs.items():
        if "emitter" in node and node["type"] == "rectangle":
            m = np.asarray(node["to_world"], np.float64)
            out["light_s"] = m[:3, 3] - m[:3, 0] - m[:3, 1]
            out["light_ex"], out["light_ey"] = 2 * m[:3, 0], 2 * m[:3, 1]
            nrm = np.linalg.inv(m[:3, :3]).T @ [0.0, 0.0, 1.0]
            out["light_n"] = nrm / np.linalg.norm(nrm)
            out["light_radiance"] = np.asarray(node["emitter"]["radiance"]["value"], float)
            continue
        if node["type"] == "constant":
            out["env"] = np.asarray(node["radiance"]["value"], float)
            continue
        bsdf = node["bsdf"]
        bsdf = bsdf.get("bsdf", bsdf)
        if bsdf["type"] != "diffuse":
            raise SystemExit(f"{name}: only diffuse materials are exported, got {bsdf['type']}")
        if node["type"] == "mesh":
            v, f = np.asarray(node["vertices"]), np.asarray(node["faces"])
            nr = np.asarray(node["normals"]) if node.get("normals") is not None else np.zeros(0)
        elif node["type"] == "rectangle":
            m = np.asarray(node["to_world"], np.float64)
            c = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], float)
            v, f, nr = (m @ c.T).T[:, :3], np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(0)
        elif node["type"] == "cube":
            sh = mi.load_dict({"type": "cube", "to_world": mi.ScalarTransform4f(
                np.asarray(node["to_world"], np.float64))})
            p = mi.traverse(sh)
            v = np.array(p["vertex_positions"]).reshape(-1, 3)
            f = np.array(p["faces"]).reshape(-1, 3)
            nr = np.zeros(0)  # flat faces
        else:
            raise SystemExit(f"{name}: shape type {node['type']} is not exported")
        out[f"v{n}"], out[f"f{n}"], out[f"n{n}"] = v, f, nr
        out[f"a{n}"] = np.asarray(bsdf["reflectance"]["value"], float)
        out[f"real{n}"] = np.array(name not in virtual)
        n += 1
    cam = scene.camera
    out.update(n_shapes=np.array(n), width=np.array(cam.width), height=np.array(cam.height),
               fx=np.array(cam.fx), fy=np.array(cam.fy), cx=np.array(cam.cx),
               cy=np.array(cam.cy), world_from_camera=np.asarray(cam.world_from_camera),
               bounces=np.array(max(max_depth - 2, 0)))
    np.savez(path, **out)


class Cycles:
    """The Blender worker process (``cycles_worker.py``) and its composites."""

    def __init__(self, python: str, scene_npz: Path, frame: np.ndarray, tmp: Path):
        self.frame, self.tmp, self.count = frame.astype(np.float64), tmp, 0
        self.proc = subprocess.Popen([python, str(HERE / "cycles_worker.py"), str(scene_npz)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, text=True)

    def render(self, spp: int, seed: int) -> tuple[np.ndarray, float]:
        """(composite, seconds) of one render."""

        self.count += 1
        out = self.tmp / f"cycles_{self.count}"
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"spp": spp, "seed": seed, "out": str(out)}) + "\n")
        self.proc.stdin.flush()
        while True:  # Blender prints its own lines on stdout too
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError("the Blender worker died")
            if line.startswith("{"):
                break
        reply = json.loads(line)
        if not reply["ok"]:
            raise RuntimeError(reply["error"])
        with np.load(f"{out}.npz") as z:
            comb, catcher = z["combined"].astype(np.float64), z["catcher"].astype(np.float64)
        os.unlink(f"{out}.npz")
        alpha = comb[..., 3:4]
        return comb[..., :3] + (1.0 - alpha) * self.frame * catcher, float(reply["seconds"])

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)


def rel_rmse(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x - ref)) / np.mean(np.square(ref))))


def rel_noise(images: list[np.ndarray], norm: float) -> float:
    """Relative RMSE of one render about its expectation from independent renders (≥ 2)."""
    var = np.var(np.stack(images), axis=0, ddof=1)
    return float(np.sqrt(np.mean(var)) / norm)


def time_to(errs: list[tuple[float, float]], target: float) -> float:
    """Time at which the log–log line through (seconds, error) reaches ``target``."""
    t, e = np.log([p[0] for p in errs]), np.log([p[1] for p in errs])
    b, a = np.polyfit(t, e, 1)
    return float(np.exp((np.log(target) - a) / b))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bpy-python", default=os.environ.get("ARLIGHT_BPY_PYTHON",
                                                           "/tmp/venv-bpy/bin/python"))
    ap.add_argument("--scene", default="bunny-box")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--spp", nargs="+", type=int, default=[4, 16, 64, 256])
    ap.add_argument("--repeats", type=int, default=3,
                    help="independent renders per spp and renderer (>= 2: the noise estimate)")
    ap.add_argument("--frame-spp", type=int, default=1024)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--only", nargs="+", default=list(ARLIGHT), choices=list(ARLIGHT),
                    help="arlight renderers to run (Cycles always runs)")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    if args.repeats < 2:
        sys.exit("--repeats must be >= 2 (the noise comes from the spread of the repeats)")
    labels = list(args.only)
    if not Path(args.bpy_python).exists():
        sys.exit(f"no Python with bpy at {args.bpy_python} (see the module docstring)")

    from arlight.evaluate.suite import get_scene
    from arlight.methods import RenderSettings, get_method
    from arlight.synthetic import synthesize

    suite = get_scene(args.scene, quick=False)
    w, h = suite.resolution
    size = (args.width, round(args.width * h / w))
    world, proxy = suite.world.resized(*size), suite.proxy.resized(*size)
    photo = synthesize(world, spp=args.frame_spp, seed=1, max_depth=args.max_depth)
    scene = proxy.with_frame(photo.frame)
    pressure = [cpu_pressure()]

    def arlight(label: str, spp: int, seed: int) -> tuple[np.ndarray, float]:
        method, opts = ARLIGHT[label]
        lay = get_method(method)(scene, RenderSettings(spp=spp, seed=seed,
                                                       max_depth=args.max_depth,
                                                       options=dict(opts)))
        return lay.composite.astype(np.float64), lay.stats["seconds"]

    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        export_scene(scene, tmp / "scene.npz", args.max_depth)
        cyc = Cycles(args.bpy_python, tmp / "scene.npz", photo.frame, tmp)
        try:
            renderers = {label: (lambda s, seed, lb=label: arlight(lb, s, seed))
                         for label in labels}
            renderers["cycles"] = cyc.render
            for r in renderers.values():  # warm-up: kernels compiled, Blender scene synced
                r(4, 7)
            runs: dict[str, dict[int, list]] = {k: {s: [] for s in args.spp} for k in renderers}
            for rep in range(args.repeats):
                for spp in args.spp:
                    for label, r in renderers.items():
                        img, sec = r(spp, 1000 + rep)
                        runs[label][spp].append((img, sec))
                        print(label, spp, rep, f"{sec:.2f} s", flush=True)
        finally:
            cyc.close()
    pressure.append(cpu_pressure())
    gt = photo.ground_truth.astype(np.float64)
    top = max(args.spp)
    pts: dict[str, list[tuple[float, float]]] = {}
    best: dict[str, np.ndarray] = {}
    for k, per_spp in runs.items():
        best[k] = np.mean([img for img, _ in per_spp[top]], axis=0)
        norm = float(np.sqrt(np.mean(np.square(best[k]))))
        pts[k] = [(float(np.mean([sec for _, sec in v])), rel_noise([img for img, _ in v], norm))
                  for v in per_spp.values()]
    t_to = {k: {t: time_to(v, t) for t in TARGETS} for k, v in pts.items()}
    slope = {k: float(np.polyfit(np.log(args.spp), np.log([e for _, e in v]), 1)[0])
             for k, v in pts.items()}
    lines = [HEADING, "",
             f"`python benchmarks/bench_vs_cycles.py --width {size[0]} --spp "
             f"{' '.join(map(str, args.spp))} --repeats {args.repeats}` — `{args.scene}` proxy "
             f"at {size[0]}×{size[1]}, max_depth {args.max_depth} (Cycles: "
             f"{args.max_depth - 2} bounces), {args.repeats} interleaved repeats per spp, "
             f"frame and ground truth {args.frame_spp} spp (Mitsuba). Noise: relative RMSE of "
             "one render about its own expectation, from the repeats' per-pixel variance. CPU "
             f"pressure (avg60) before/after: {pressure[0] or 'n/a'} / {pressure[1] or 'n/a'} %.",
             "",
             "| renderer | time to 5 % (s) | to 2.5 % | to 1 % | Cycles time / its time at "
             "2.5 % | at 1 % | noise slope vs spp | mean of top-spp renders vs ground truth "
             "(rel. RMSE / its noise) |",
             "|---|---|---|---|---|---|---|---|"]
    for k in renderers:
        tt = t_to[k]
        own = pts[k][-1][1] / np.sqrt(args.repeats)
        lines.append(f"| {k} | {tt[0.05]:.3g} | {tt[0.025]:.3g} | {tt[0.01]:.3g} | "
                     f"{t_to['cycles'][0.025] / tt[0.025]:.2f} | "
                     f"{t_to['cycles'][0.01] / tt[0.01]:.2f} | {slope[k]:.3f} | "
                     f"{rel_rmse(best[k], gt):.4f} / {own:.4f} |")
    lines += ["", "Points (mean seconds, noise) per spp " + str(args.spp) + ":", ""]
    for k, v in pts.items():
        lines.append(f"* {k}: " + ", ".join(f"({s:.2f}, {e:.4f})" for s, e in v))
    publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
