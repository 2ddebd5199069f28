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
renderer and ``spp`` in ``--spp``, the wall time (arlight: the whole method call, scene
preparation included; Cycles: its synchronisation + render time from the EXR metadata) and
the relative RMSE ``‖x − c‖ / ‖c‖`` against the renderer's *own* converged composite ``c``
(``--gt-spp``); a least-squares line through log error against log time gives the time to
reach 5 %, 2.5 % and 1 %. Correctness: each converged composite's relative RMSE against the
ground-truth photograph (Mitsuba, the world with the virtual objects).

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
    "onepass blocks": ("onepass", {"reproject": False, "replica_mode": "blocks"}),
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
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--gt-spp", type=int, default=4096)
    ap.add_argument("--frame-spp", type=int, default=1024)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
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
                         for label in ARLIGHT}
            renderers["cycles"] = cyc.render
            for r in renderers.values():  # warm-up: kernels compiled, Blender scene synced
                r(4, 7)
            conv = {label: r(args.gt_spp, 99)[0] for label, r in renderers.items()}
            pts: dict[str, list[tuple[float, float]]] = {k: [] for k in renderers}
            for rep in range(args.repeats):
                for spp in args.spp:
                    for label, r in renderers.items():
                        img, sec = r(spp, 1000 + rep)
                        pts[label].append((sec, rel_rmse(img, conv[label])))
                        print(label, spp, pts[label][-1], flush=True)
        finally:
            cyc.close()
    pressure.append(cpu_pressure())
    gt = photo.ground_truth.astype(np.float64)
    t_to = {k: {t: time_to(v, t) for t in TARGETS} for k, v in pts.items()}
    lines = [HEADING, "",
             f"`python benchmarks/bench_vs_cycles.py` — `{args.scene}` proxy at {size[0]}×"
             f"{size[1]}, max_depth {args.max_depth} (Cycles: {args.max_depth - 2} bounces), "
             f"spp {args.spp} × {args.repeats} interleaved repeats, converged images at "
             f"{args.gt_spp} spp, frame and ground truth {args.frame_spp} spp (Mitsuba). "
             f"CPU pressure (avg60) before/after: {pressure[0] or 'n/a'} / "
             f"{pressure[1] or 'n/a'} %.", "",
             "| renderer | time to 5 % (s) | to 2.5 % | to 1 % | Cycles time / its time at "
             "2.5 % | at 1 % | converged vs ground truth (rel. RMSE) |",
             "|---|---|---|---|---|---|---|"]
    for k in renderers:
        tt = t_to[k]
        lines.append(f"| {k} | {tt[0.05]:.3g} | {tt[0.025]:.3g} | {tt[0.01]:.3g} | "
                     f"{t_to['cycles'][0.025] / tt[0.025]:.2f} | "
                     f"{t_to['cycles'][0.01] / tt[0.01]:.2f} | {rel_rmse(conv[k], gt):.4f} |")
    lines += ["", "Raw points (seconds, relative RMSE vs own converged image), spp ascending "
              "per repeat:", ""]
    for k, v in pts.items():
        lines.append(f"* {k}: " + ", ".join(f"({s:.2f}, {e:.4f})" for s, e in v))
    publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
