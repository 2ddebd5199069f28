"""Blender worker of ``bench_vs_cycles.py``: builds the AR scene in Cycles and renders on
request. Runs under a Python that has ``bpy`` (the ``bench`` extra, in its own virtual
environment: bpy 5.0 pins numpy < 2); talks over stdin/stdout, one JSON object a line.

    python cycles_worker.py scene.npz
    stdin:  {"spp": 64, "seed": 3, "out": "/tmp/x"}
    stdout: {"ok": true, "seconds": 1.23}     (Cycles' synchronisation + render time)

The passes go to ``out.npz`` (``combined`` RGBA premultiplied, ``catcher`` RGB: the
*Shadow Catcher* pass), read from Blender's multi-part EXR with its bundled OpenImageIO.

The scene file (written by the benchmark) holds, per shape, world-space triangles, smooth
normals (or none), a Lambertian albedo and a role (``real`` shapes are shadow catchers);
the one-sided rectangular area light (corner, edges, radiance), the constant environment
radiance, the camera (world_from_camera in arlight's convention: +z forward, +y down; focal
lengths and resolution) and the bounce limit.
"""

from __future__ import annotations

import json
import math
import sys

import bpy
import mathutils
import numpy as np


def build(path: str) -> None:
    d = np.load(path, allow_pickle=False)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.use_denoising = False
    cy.use_adaptive_sampling = False
    cy.max_bounces = int(d["bounces"])
    for k in ("diffuse_bounces", "glossy_bounces", "transmission_bounces"):
        setattr(cy, k, int(d["bounces"]))
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.caustics_reflective = True
    cy.caustics_refractive = True
    cy.blur_glossy = 0.0
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    sc.render.film_transparent = True
    w, h = int(d["width"]), int(d["height"])
    sc.render.resolution_x, sc.render.resolution_y = w, h
    sc.render.resolution_percentage = 100
    sc.render.threads_mode = "AUTO"
    sc.view_layers[0].cycles.use_pass_shadow_catcher = True
    sc.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    sc.render.image_settings.color_depth = "32"
    # world: constant radiance
    world = bpy.data.worlds.new("env")
    sc.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    env = [float(x) for x in d["env"]]
    bg.inputs[0].default_value = (*env, 1.0)
    bg.inputs[1].default_value = 1.0
    # camera: Blender looks along -z with +y up; arlight along +z with +y down
    cam = bpy.data.cameras.new("cam")
    cam.sensor_fit = "VERTICAL"
    cam.sensor_height = 24.0
    cam.lens = float(d["fy"]) * 24.0 / h
    cam.shift_x = -(float(d["cx"]) - w / 2) / max(w, h)
    cam.shift_y = (float(d["cy"]) - h / 2) / max(w, h)
    cam.clip_start = 1e-3
    co = bpy.data.objects.new("cam", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    m = np.asarray(d["world_from_camera"], np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
    co.matrix_world = mathutils.Matrix(m.tolist())  # rows
    # shapes
    for i in range(int(d["n_shapes"])):
        v, f = d[f"v{i}"], d[f"f{i}"]
        me = bpy.data.meshes.new(f"s{i}")
        me.from_pydata(v.tolist(), [], f.tolist())
        me.update()
        n = d[f"n{i}"]
        if n.size:
            me.shade_smooth()
            me.normals_split_custom_set_from_vertices(n.tolist())
        mat = bpy.data.materials.new(f"m{i}")
        mat.use_nodes = True
        nt = mat.node_tree
        nt.nodes.clear()
        diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
        diff.inputs[0].default_value = (*[float(x) for x in d[f"a{i}"]], 1.0)
        diff.inputs[1].default_value = 0.0  # Lambertian
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(diff.outputs[0], out.inputs[0])
        me.materials.append(mat)
        ob = bpy.data.objects.new(f"s{i}", me)
        ob.is_shadow_catcher = bool(d[f"real{i}"])
        sc.collection.objects.link(ob)
    # the rectangular area light: Blender's radiance is P / (π A), emitted along local -z
    s, ex, ey = (np.asarray(d[k], np.float64) for k in ("light_s", "light_ex", "light_ey"))
    nrm = np.asarray(d["light_n"], np.float64)
    rad = np.asarray(d["light_radiance"], np.float64)
    lmax = float(rad.max())
    light = bpy.data.lights.new("rect", type="AREA")
    light.shape = "RECTANGLE"
    light.size, light.size_y = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
    light.color = tuple(float(c) / lmax for c in rad)
    light.energy = math.pi * light.size * light.size_y * lmax
    if hasattr(light, "use_soft_falloff"):
        light.use_soft_falloff = False  # physically exact falloff
    lo = bpy.data.objects.new("rect", light)
    x, y = ex / np.linalg.norm(ex), ey / np.linalg.norm(ey)
    z = -nrm  # emits along local -z
    y = np.cross(z, x)
    centre = s + 0.5 * ex + 0.5 * ey
    mw = np.eye(4)
    mw[:3, 0], mw[:3, 1], mw[:3, 2], mw[:3, 3] = x, y, z, centre
    lo.matrix_world = mathutils.Matrix(mw.tolist())
    lo.visible_camera = True
    # a light marked as shadow catcher is part of the real scene (the footage holds its light):
    # the Shadow Catcher pass is then exactly 1 without virtual objects; unmarked, Cycles
    # treats it as an added light whose light the catchers "catch" (the pass ≈ 8 here)
    lo.is_shadow_catcher = True
    sc.collection.objects.link(lo)


def _oiio():
    try:
        import OpenImageIO
    except ImportError:  # Blender's bundled modules
        sys.path.append(bpy.utils.system_resource("SCRIPTS")
                        + "/../python/lib/python3.11/site-packages")
        import OpenImageIO
    return OpenImageIO


def _clock(text: str) -> float:
    """Blender's ``[hh:]mm:ss.xx`` to seconds."""
    sec = 0.0
    for x in str(text).split(":"):
        sec = sec * 60 + float(x)
    return sec


def render(spp: int, seed: int, out: str) -> float:
    """Render ``spp`` samples with ``seed``; the passes go to ``out.npz``; returns Cycles'
    synchronisation + render seconds (from the EXR's metadata)."""
    sc = bpy.context.scene
    sc.cycles.samples = int(spp)
    sc.cycles.seed = int(seed)
    exr = out + ".exr"
    sc.render.filepath = exr
    bpy.ops.render.render(write_still=True)
    oiio = _oiio()
    inp = oiio.ImageInput.open(exr)
    passes, seconds, i = {}, None, 0
    while inp.seek_subimage(i, 0):
        spec = inp.spec()
        t = spec.getattribute("cycles.ViewLayer.total_time")
        if t is not None:
            seconds = _clock(t)
        px = np.asarray(inp.read_image("float"), np.float32)
        for c, name in enumerate(spec.channelnames):
            passes[name] = px[..., c]
        i += 1
    inp.close()
    import os
    os.unlink(exr)
    comb = np.stack([passes[f"ViewLayer.Combined.{c}"] for c in "RGBA"], -1)
    catcher = np.stack([passes[f"ViewLayer.Shadow Catcher.{c}"] for c in "RGB"], -1)
    np.savez(out + ".npz", combined=comb, catcher=catcher)
    if seconds is None:
        raise RuntimeError("no cycles.ViewLayer.total_time in the EXR metadata")
    return seconds


def main() -> None:
    build(sys.argv[1])
    for line in sys.stdin:
        job = json.loads(line)
        try:
            sec = render(job["spp"], job["seed"], job["out"])
            print(json.dumps({"ok": True, "seconds": sec}), flush=True)
        except Exception as exc:  # report, keep serving
            print(json.dumps({"ok": False, "error": repr(exc)}), flush=True)


if __name__ == "__main__":
    main()
