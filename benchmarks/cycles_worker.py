"""Blender worker of ``bench_vs_cycles.py``: builds a scene in Cycles and renders on request.
Runs under a Python that has ``bpy`` (the ``bench`` extra, in its own virtual environment:
bpy 5.0 pins numpy < 2); talks over stdin/stdout, one JSON object a line.

    python cycles_worker.py scene.npz
    stdin:  {"spp": 64, "seed": 3, "out": "/tmp/x", "denoise": false}
    stdout: {"ok": true, "seconds": 1.23, "sync": 0.2, "wall": 1.3}   (Cycles' synchronisation
            + render time, the synchronisation's alone — with an environment map mostly the
            bake of its importance map, Cycles' default "Automatic" resolution 1024 — and the
            wall time of the whole render call, denoising and the EXR write included)

``denoise``: Cycles' own OpenImageDenoise on the CPU (quality High, albedo and normal
auxiliary passes, accurate prefilter: its best), applied to every pass it denoises (Combined
and the Shadow Catcher).

The passes go to ``out.npz`` (``combined`` RGBA premultiplied, and in a catcher scene
``catcher`` RGB: the *Shadow Catcher* pass), read from Blender's multi-part EXR with its
bundled OpenImageIO.

The scene file (written by ``bench_vs_cycles.export_scene``, which says how each Mitsuba
object is translated) holds a JSON ``manifest`` — camera (world_from_camera in arlight's
convention: +z forward, +y down; focal lengths, principal point, resolution, thin lens),
bounce limit, environment, lights (already in Blender's units), shapes (material, role,
smoothness) and whether real shapes and lights are shadow catchers — and the arrays it names:
per shape ``v<i>`` world-space vertices, ``f<i>`` triangles, optional ``n<i>`` vertex normals
and ``uv<i>`` texture coordinates; images (``env``, ``img<k>``) as (H, W, 3) linear float
arrays with row 0 at the top, as Mitsuba reads them.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time

import bpy
import mathutils
import numpy as np


def _image(name: str, rgb: np.ndarray, top_row_at_v1: bool):
    """A float Blender image of (H, W, 3) pixels (no colour transform). Blender stores rows
    bottom-up (v = 0 is the first row): an equirectangular map has its top row at v = 1, a
    Mitsuba texture its row 0 at v = 0."""
    h, w = rgb.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = rgb
    if top_row_at_v1:
        rgba = rgba[::-1]
    img.pixels.foreach_set(np.ascontiguousarray(rgba).ravel())
    img.pack()
    return img


def _frame(z, x=None) -> mathutils.Matrix:
    """A 4×4 rotation whose local z axis is ``z`` (and x axis ``x`` when given)."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    if x is None:
        a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = a - z * np.dot(a, z)
    x = np.asarray(x, float) / np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m


def _world(sc, spec: dict, d) -> None:
    world = bpy.data.worlds.new("env")
    sc.world = world
    nt = world.node_tree
    bg = nt.nodes["Background"]
    if spec["type"] == "none":
        bg.inputs[0].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs[1].default_value = 0.0
    elif spec["type"] == "constant":
        bg.inputs[0].default_value = (*spec["color"], 1.0)
        bg.inputs[1].default_value = 1.0
    else:
        _envmap(nt, bg, spec, d[spec["image"]])


def _envmap(nt, bg, spec: dict, rgb: np.ndarray) -> None:
    """The map looked up as Mitsuba's ``envmap`` does. The direction turns into Blender's
    equirectangular frame (``spec["matrix"]``, see ``bench_vs_cycles.envmap_axes``); then
    its polar angle θ is remapped: Mitsuba reads row ``v (H − 1)`` at ``v = θ / π`` (rows
    corner-aligned) where Blender reads row ``v H − 1/2`` (centre-aligned, as both do for
    columns), so Blender is given ``θ' = θ (H − 1) / H + π / 2H`` at the same azimuth."""
    h = rgb.shape[0]

    def node(kind, op=None, *inputs):
        n = nt.nodes.new(kind)
        if op is not None:
            n.operation = op
        for i, x in enumerate(inputs):
            if isinstance(x, bpy.types.NodeSocket):
                nt.links.new(x, n.inputs[i])
            elif x is not None:
                n.inputs[i].default_value = x
        return n

    math_ = "ShaderNodeMath"
    coord = nt.nodes.new("ShaderNodeTexCoord")
    unit = node("ShaderNodeVectorMath", "NORMALIZE", coord.outputs["Generated"])
    rot = node("ShaderNodeCombineXYZ")
    for i, row in enumerate(spec["matrix"]):
        dot = node("ShaderNodeVectorMath", "DOT_PRODUCT", unit.outputs["Vector"], row)
        nt.links.new(dot.outputs["Value"], rot.inputs[i])
    b = node("ShaderNodeSeparateXYZ", None, rot.outputs[0])
    theta = node(math_, "ARCCOSINE", b.outputs["Z"])
    theta2 = node(math_, "MULTIPLY_ADD", theta.outputs[0], (h - 1) / h, math.pi / (2 * h))
    sin1 = node(math_, "SINE", theta.outputs[0])
    sin2 = node(math_, "SINE", theta2.outputs[0])
    cos2 = node(math_, "COSINE", theta2.outputs[0])
    scale = node(math_, "DIVIDE", sin2.outputs[0], sin1.outputs[0])
    x = node(math_, "MULTIPLY", b.outputs["X"], scale.outputs[0])
    y = node(math_, "MULTIPLY", b.outputs["Y"], scale.outputs[0])
    vec = node("ShaderNodeCombineXYZ", None, x.outputs[0], y.outputs[0], cos2.outputs[0])
    tex = nt.nodes.new("ShaderNodeTexEnvironment")
    tex.image = _image("env", rgb, top_row_at_v1=True)
    tex.interpolation = "Linear"
    nt.links.new(vec.outputs[0], tex.inputs[0])
    nt.links.new(tex.outputs[0], bg.inputs[0])
    bg.inputs[1].default_value = spec["scale"]


def _material(i: int, spec: dict, d):
    mat = bpy.data.materials.new(f"m{i}")
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    t = spec["type"]
    if t == "diffuse":
        b = nt.nodes.new("ShaderNodeBsdfDiffuse")
        b.inputs["Roughness"].default_value = 0.0  # Lambertian
        if "texture" in spec:
            tex = nt.nodes.new("ShaderNodeTexImage")
            tex.image = _image(spec["texture"], d[spec["texture"]], top_row_at_v1=False)
            tex.interpolation = "Linear"
            tex.extension = "REPEAT"
            nt.links.new(tex.outputs["Color"], b.inputs["Color"])
        else:
            b.inputs["Color"].default_value = (*spec["color"], 1.0)
    elif t == "glossy":
        b = nt.nodes.new("ShaderNodeBsdfGlossy")
        b.distribution = "GGX"
        b.inputs["Color"].default_value = (*spec["color"], 1.0)
        b.inputs["Roughness"].default_value = spec["roughness"]
        b.inputs["Anisotropy"].default_value = 0.0
    elif t == "glass":
        b = nt.nodes.new("ShaderNodeBsdfGlass")
        b.distribution = "GGX"
        b.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        b.inputs["Roughness"].default_value = 0.0
        b.inputs["IOR"].default_value = spec["ior"]
    else:
        raise ValueError(f"material {t}")
    nt.links.new(b.outputs[0], out.inputs["Surface"])
    return mat


def _light(i: int, spec: dict, catcher: bool):
    t = spec["type"]
    light = bpy.data.lights.new(f"l{i}", type=t)
    light.color = spec["color"]
    light.energy = spec["energy"]
    if hasattr(light, "use_soft_falloff"):
        light.use_soft_falloff = False  # physically exact falloff
    m = np.eye(4)
    if t == "POINT":
        light.shadow_soft_size = spec["radius"]
        m[:3, 3] = spec["position"]
    elif t == "SUN":
        light.angle = 0.0
        m = _frame(-np.asarray(spec["direction"]))  # emits along its local -z
    elif t == "SPOT":
        light.shadow_soft_size = 0.0
        light.spot_size = math.radians(2 * spec["cutoff_deg"])
        light.spot_blend = 0.0
        axis = np.asarray(spec["direction"], float)
        m = _frame(-axis)
        m[:3, 3] = spec["position"]
        # Mitsuba's profile: 1 inside the beam, linear in angle to 0 at the cutoff
        light.use_nodes = True
        nt = light.node_tree
        em = nt.nodes["Emission"]
        geo = nt.nodes.new("ShaderNodeNewGeometry")
        dot = nt.nodes.new("ShaderNodeVectorMath")
        dot.operation = "DOT_PRODUCT"
        nt.links.new(geo.outputs["Normal"], dot.inputs[0])
        dot.inputs[1].default_value = axis.tolist()
        ab = nt.nodes.new("ShaderNodeMath")
        ab.operation = "ABSOLUTE"
        nt.links.new(dot.outputs["Value"], ab.inputs[0])
        ac = nt.nodes.new("ShaderNodeMath")
        ac.operation = "ARCCOSINE"
        nt.links.new(ab.outputs[0], ac.inputs[0])
        lin = nt.nodes.new("ShaderNodeMath")
        lin.operation = "MULTIPLY_ADD"  # (θ − cutoff) · (−1/width) = (cutoff − θ) / width
        lin.use_clamp = True
        width = math.radians(spec["cutoff_deg"] - spec["beam_deg"])
        nt.links.new(ac.outputs[0], lin.inputs[0])
        lin.inputs[1].default_value = -1.0 / width
        lin.inputs[2].default_value = math.radians(spec["cutoff_deg"]) / width
        nt.links.new(lin.outputs[0], em.inputs["Strength"])
    elif t == "AREA":
        light.shape = "RECTANGLE"
        light.size, light.size_y = spec["size"]
        m = _frame(-np.asarray(spec["normal"]), spec["x"])  # emits along its local -z
        m[:3, 3] = spec["position"]
    lo = bpy.data.objects.new(f"l{i}", light)
    lo.matrix_world = mathutils.Matrix(m.tolist())
    # in the AR render the frame shows the real lights (and the Combined pass would add them
    # a second time); reflections of them in virtual objects stay
    lo.visible_camera = not catcher
    # a light marked as shadow catcher is part of the real scene (the footage holds its light):
    # the Shadow Catcher pass is then exactly 1 without virtual objects; unmarked, Cycles
    # treats it as an added light whose light the catchers "catch"
    lo.is_shadow_catcher = catcher
    bpy.context.scene.collection.objects.link(lo)


def build(path: str) -> None:
    d = np.load(path, allow_pickle=False)
    man = json.loads(str(d["manifest"]))
    catcher = bool(man["catcher"])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.use_denoising = False
    cy.use_adaptive_sampling = False
    cy.max_bounces = int(man["bounces"])
    for k in ("diffuse_bounces", "glossy_bounces", "transmission_bounces"):
        setattr(cy, k, int(man["bounces"]))
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.light_sampling_threshold = 0.0  # no light is skipped as too dim (unbiased)
    cy.caustics_reflective = True
    cy.caustics_refractive = True
    cy.blur_glossy = 0.0
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    sc.render.film_transparent = catcher
    cam_spec = man["camera"]
    w, h = cam_spec["width"], cam_spec["height"]
    sc.render.resolution_x, sc.render.resolution_y = w, h
    sc.render.resolution_percentage = 100
    sc.render.threads_mode = "AUTO"
    if catcher:
        sc.view_layers[0].cycles.use_pass_shadow_catcher = True
    sc.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    sc.render.image_settings.color_depth = "32"
    _world(sc, man["world"], d)
    # camera: Blender looks along -z with +y up; arlight along +z with +y down
    cam = bpy.data.cameras.new("cam")
    cam.sensor_fit = "VERTICAL"
    cam.sensor_height = 24.0
    cam.lens = cam_spec["fy"] * 24.0 / h
    cam.shift_x = -(cam_spec["cx"] - w / 2) / max(w, h)
    cam.shift_y = (cam_spec["cy"] - h / 2) / max(w, h)
    cam.clip_start = 1e-4
    cam.clip_end = 1e6
    if cam_spec["aperture_radius"] > 0:
        cam.dof.use_dof = True
        cam.dof.focus_distance = cam_spec["focus_distance"]
        # Cycles' aperture radius is lens[m] / (2 N) (bench_vs_cycles.aperture_fstop)
        cam.dof.aperture_fstop = cam.lens * 1e-3 / (2.0 * cam_spec["aperture_radius"])
        cam.dof.aperture_blades = 0
        cam.dof.aperture_ratio = 1.0
    co = bpy.data.objects.new("cam", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    m = np.asarray(cam_spec["world_from_camera"], np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
    co.matrix_world = mathutils.Matrix(m.tolist())  # rows
    for i, spec in enumerate(man["shapes"]):
        v, f = d[f"v{i}"], d[f"f{i}"]
        me = bpy.data.meshes.new(f"s{i}")
        me.from_pydata(v.tolist(), [], f.tolist())
        me.update()
        if spec["uv"]:
            uv = d[f"uv{i}"]
            layer = me.uv_layers.new(name="UVMap")
            loops = np.zeros(len(me.loops), np.int64)
            me.loops.foreach_get("vertex_index", loops)
            layer.data.foreach_set("uv", uv[loops].astype(np.float32).ravel())
        if spec["smooth"]:
            me.shade_smooth()
            if spec["normals"]:
                me.normals_split_custom_set_from_vertices(d[f"n{i}"].tolist())
        else:
            me.shade_flat()
        me.materials.append(_material(i, spec["material"], d))
        ob = bpy.data.objects.new(f"s{i}", me)
        ob.is_shadow_catcher = catcher and spec["real"]
        ob.shadow_terminator_geometry_offset = 0.0  # Mitsuba offsets no shadow rays
        sc.collection.objects.link(ob)
    for i, spec in enumerate(man["lights"]):
        _light(i, spec, catcher)


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


def set_denoise(on: bool) -> None:
    """Cycles' OpenImageDenoise (CPU, High, albedo + normal, accurate prefilter) on or off."""
    cy = bpy.context.scene.cycles
    cy.use_denoising = bool(on)
    if on:
        cy.denoiser = "OPENIMAGEDENOISE"
        cy.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        cy.denoising_prefilter = "ACCURATE"
        cy.denoising_quality = "HIGH"
        cy.denoising_use_gpu = False


def render(spp: int, seed: int, out: str, denoise: bool = False
           ) -> tuple[float, float | None, float]:
    """Render ``spp`` samples with ``seed`` (``denoise``: with Cycles' OIDN); the passes go to
    ``out.npz``; returns Cycles' synchronisation + render seconds and the synchronisation's
    (from the EXR's metadata), and the wall time of the render call."""
    sc = bpy.context.scene
    sc.cycles.samples = int(spp)
    sc.cycles.seed = int(seed)
    set_denoise(denoise)
    exr = out + ".exr"
    sc.render.filepath = exr
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    wall = time.perf_counter() - t0
    oiio = _oiio()
    inp = oiio.ImageInput.open(exr)
    passes, seconds, sync, i = {}, None, None, 0
    while inp.seek_subimage(i, 0):
        spec = inp.spec()
        t = spec.getattribute("cycles.ViewLayer.total_time")
        if t is not None:
            seconds = _clock(t)
        t = spec.getattribute("cycles.ViewLayer.synchronization_time")
        if t is not None:
            sync = _clock(t)
        px = np.asarray(inp.read_image("float"), np.float32)
        for c, name in enumerate(spec.channelnames):
            passes[name] = px[..., c]
        i += 1
    inp.close()
    os.unlink(exr)
    arrays = {"combined": np.stack([passes[f"ViewLayer.Combined.{c}"] for c in "RGBA"], -1)}
    if "ViewLayer.Shadow Catcher.R" in passes:
        arrays["catcher"] = np.stack([passes[f"ViewLayer.Shadow Catcher.{c}"] for c in "RGB"],
                                     -1)
    np.savez(out + ".npz", **arrays)
    if seconds is None:
        raise RuntimeError("no cycles.ViewLayer.total_time in the EXR metadata")
    return seconds, sync, wall


def main() -> None:
    build(sys.argv[1])
    for line in sys.stdin:
        job = json.loads(line)
        try:
            sec, sync, wall = render(job["spp"], job["seed"], job["out"],
                                     bool(job.get("denoise", False)))
            print(json.dumps({"ok": True, "seconds": sec, "sync": sync, "wall": wall}),
                  flush=True)
        except Exception as exc:  # report, keep serving
            print(json.dumps({"ok": False, "error": repr(exc)}), flush=True)


if __name__ == "__main__":
    main()
