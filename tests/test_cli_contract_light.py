"""The bad-input contract (docs/cli.md) for ``import-mitsuba``, ``light probeless``,
``light atlas``, ``light show`` and ``light estimate``: every case exits 2 with one
``error:`` line naming the file or field, no traceback, the inputs and earlier outputs byte
for byte as they were (no file added), and a bounded peak memory.

The cases are generated: each output option pointed at each input file (and at the files the
inputs reference: the meshes and maps of a scene, the images of an RGB-D folder or a rig), at
a file a person made, a folder, a dangling symlink, arlight's ledger; each number option at
NaN, Inf and beyond its cap; light files with NaN/Inf/absurd values; image headers that claim
sizes no machine could hold (refused by the estimate before anything is read).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from arlight.io.images import write_exr, write_png
from tests.cli_harness import Case, check, clean_env

MAX_RSS_MB = 1200
"""Peak memory a refused case may reach (imports ~400-600 MiB; no case may allocate what a
bad size asks for)."""

XML = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="{fov}"/>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/>
    </film></sensor>
  <shape type="rectangle" id="floor"><bsdf type="diffuse"/></shape>
  <shape type="ply" id="blob"><string name="filename" value="scene.blob.ply"/>
    <bsdf type="diffuse"/></shape>
  <emitter type="envmap"><string name="filename" value="{sky}"/></emitter>
</scene>
"""

LIGHT = {"format": "arlight.light_estimate", "version": 1,
         "main_light": {"direction_to_light": [0, 1, 0], "irradiance": [1, 1, 1]},
         "sh": {"order": 1, "quantity": "radiance", "basis": "arlight",
                "coefficients": [[0.1, 0.1, 0.1]] * 4}, "lights": [],
         "timestamp": 0.0, "confidence": 1.0}


def _huge_exr(small: Path, out: Path, w: int = 200_000, h: int = 100_000) -> None:
    """A copy of the EXR ``small`` whose header claims ``w × h`` pixels."""
    data = bytearray(small.read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at:at + 16] = struct.pack("<4i", 0, 0, w - 1, h - 1)
    out.write_bytes(bytes(data))


def _huge_png(out: Path, w: int = 150_000, h: int = 150_000) -> None:
    """A PNG whose header claims ``w × h`` pixels (the data is one empty row)."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    out.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                    + chunk(b"IDAT", zlib.compress(b"\0")) + chunk(b"IEND", b""))


def _ply(path: Path) -> None:
    import trimesh

    mesh = trimesh.creation.icosphere(1, radius=0.2)
    path.write_bytes(trimesh.exchange.ply.export_ply(mesh))


def _import_cases(root: Path) -> list[Case]:
    d = root / "imp"
    d.mkdir()
    _ply(d / "scene.blob.ply")
    write_exr(d / "sky.exr", np.full((8, 16, 3), 0.5, np.float32))
    _huge_exr(d / "sky.exr", d / "hugesky.exr")
    (d / "scene.xml").write_text(XML.format(fov=45, sky="sky.exr"))
    for name, fov in (("nan", "nan"), ("zero", "0"), ("wide", "200")):
        (d / f"fov_{name}.xml").write_text(XML.format(fov=fov, sky="sky.exr"))
    (d / "huge.xml").write_text(XML.format(fov=45, sky="hugesky.exr"))
    prev = root / "imp_prev"  # earlier outputs and a person's files
    prev.mkdir()
    (prev / "mine.toml").write_text("# my notes\n")
    (prev / "out.blob.ply").write_text("a person's mesh")
    (prev / "afile").write_text("x")
    os.symlink(root / "nowhere", prev / "dangling")
    xml = str(d / "scene.xml")
    keep = [d, prev]
    cases = []
    for name, out, needle in [
        ("over-xml", d / "scene.xml", "scene.xml"),
        ("over-referenced-mesh", d / "scene.blob.ply", "scene.blob.ply"),
        ("side-file-is-input", d / "scene.toml", "scene.blob.ply"),
        ("side-file-foreign", prev / "out.toml", "out.blob.ply"),
        ("foreign-toml", prev / "mine.toml", "--overwrite"),
        ("folder", prev, "folder"),
        ("dangling", prev / "dangling", "dangling"),
        ("under-dangling", prev / "dangling" / "x.toml", "dangling"),
        ("under-file", prev / "afile" / "x.toml", "not a folder"),
        ("ledger", prev / ".arlight-written.json", "record"),
    ]:
        cases.append(Case(f"import-o-{name}", ["import-mitsuba", xml, "-o", str(out)],
                          [needle], keep=keep))
    for name in ("nan", "zero", "wide"):
        cases.append(Case(f"import-fov-{name}", ["import-mitsuba", str(d / f"fov_{name}.xml"),
                          "-o", str(prev / "f.toml")], ["fov"], keep=keep))
    cases += [
        Case("import-huge-map", ["import-mitsuba", str(d / "huge.xml"), "-o",
             str(prev / "h.toml")], ["--force"], keep=keep),
        Case("import-missing", ["import-mitsuba", str(d / "nope.xml"), "-o",
             str(prev / "m.toml")], ["nope.xml"], keep=keep),
        Case("import-xml-folder", ["import-mitsuba", str(d), "-o", str(prev / "m.toml")],
             ["folder"], keep=keep),
        Case("import-virtual-unknown", ["import-mitsuba", xml, "--virtual", "nope", "-o",
             str(prev / "v.toml")], ["--virtual"], keep=keep),
    ]
    return cases


def _probeless_cases(root: Path) -> list[Case]:
    seq = root / "seq"
    (seq / "color").mkdir(parents=True)
    (seq / "depth").mkdir()
    write_png(seq / "color" / "000.png", np.full((12, 16, 3), 128, np.uint8))
    import cv2

    cv2.imwrite(str(seq / "depth" / "000.png"), np.full((12, 16), 1500, np.uint16))
    (seq / "intrinsics.json").write_text(json.dumps({"fx": 20, "fy": 20, "cx": 8, "cy": 6}))
    (seq / "poses.txt").write_text("0 0 0 0 0 0 1\n")
    big = root / "bigseq"
    (big / "color").mkdir(parents=True)
    (big / "depth").mkdir()
    _huge_png(big / "color" / "000.png")
    _huge_png(big / "depth" / "000.png")
    (big / "poses.txt").write_text("0 0 0 0 0 0 1\n")
    prev = root / "pl_prev"
    prev.mkdir()
    (prev / "light.json").write_text('{"mine": true}')
    (prev / "other.json").write_text("{}")  # -o other.json: ...
    (prev / "other.frames.json").write_text('{"mine": true}')  # its per-frame file: mine
    keep = [seq, big, prev]
    base = ["light", "probeless", str(seq), "--poses", str(seq / "poses.txt")]
    free = ["-o", str(prev / "new.json")]
    cases = []
    for name, args, needle in [
        ("o-intrinsics", ["-o", str(seq / "intrinsics.json")], "intrinsics.json"),
        ("o-colour", ["-o", str(seq / "color" / "000.png")], "000.png"),
        ("o-poses", ["-o", str(seq / "poses.txt")], "poses.txt"),
        ("mesh-depth", [*free, "--mesh", str(seq / "depth" / "000.png")], "000.png"),
        ("mesh-new-in-colour", [*free, "--mesh", str(seq / "color" / "zz.ply")],
         "image folder"),
        ("o-foreign", ["-o", str(prev / "light.json")], "--overwrite"),
        ("frames-file-foreign", ["-o", str(prev / "other.json")], "other"),
        ("mesh-is-output", [*free, "--mesh", str(prev / "new.json")], "twice"),
        ("o-folder", ["-o", str(prev)], "folder"),
        ("resolution-cap", [*free, "--resolution", "5000"], "--resolution"),
        ("volume-nan", [*free, "--volume", "nan"], "--volume"),
        ("max-frames-0", [*free, "--max-frames", "0"], "--max-frames"),
        ("intrinsics-nan", [*free, "--intrinsics", "nan,20,8,6"], "--intrinsics"),
    ]:
        cases.append(Case(f"probeless-{name}", [*base, *args], [needle], keep=keep))
    cases.append(Case("probeless-huge-frames", ["light", "probeless", str(big), "--poses",
                      str(big / "poses.txt"), "--intrinsics", "20,20,8,6", *free],
                      ["--force"], keep=keep))
    return cases


def _atlas_cases(root: Path) -> list[Case]:
    nf = root / "nf"
    nf.mkdir()
    _ply(nf / "mesh.ply")
    (nf / "scene.toml").write_text('[[shapes]]\nname = "m"\ntype = "mesh"\n'
                                   'file = "mesh.ply"\n')
    write_exr(nf / "a.exr", np.full((32, 32, 3), 0.2, np.float32))
    cam = ('[[cameras]]\nname = "c"\nposition = [0, 1, 0]\nlook = {look}\nup = [0, 1, 0]\n'
           'equidistant = {{ size = {size}, fov_deg = {fov} }}\nimage = "a.exr"\n')
    (nf / "cams.toml").write_text(cam.format(look="[0, 0, -1]", size="[32, 32]", fov=180.0))
    rigs = {"size": ("[0, 0, -1]", "[100000, 100000]", 180.0),
            "fov": ("[0, 0, -1]", "[32, 32]", "nan"),
            "look": ("[0, 0, 0]", "[32, 32]", 180.0)}
    for name, (look, size, fov) in rigs.items():
        (nf / f"rig_{name}.toml").write_text(cam.format(look=look, size=size, fov=fov))
    (nf / "rig_big.toml").write_text("".join(
        cam.replace('image = "a.exr"\n', "").replace('"c"', f'"c{k}"').format(
            look="[0, 0, -1]", size="[16384, 16384]", fov=180.0) for k in range(6)))
    prev = root / "nf_prev"
    prev.mkdir()
    (prev / "vals.json").write_text('{"mine": true}')
    keep = [nf, prev]
    from arlight.scene.save import save_scene
    from tests.nearfield.conftest import room, scene, vbox

    save_scene(scene(room(virtual=[vbox()])), nf / "room.toml")
    base = ["light", "atlas", str(nf / "scene.toml"), "--cameras", str(nf / "cams.toml")]
    free = ["-o", str(prev / "new.json")]
    cases = []
    for name, args, needle in [
        ("vals-1e9", [*free, "--vals", "1000000000"], "--vals"),
        ("atlas-huge", [*free, "--atlas", "100000"], "--atlas"),
        ("size-huge", [*free, "--size", "100000"], "--size"),
        ("tau-nan", [*free, "--tau", "nan"], "τ"),
        ("o-scene", ["-o", str(nf / "scene.toml")], "scene.toml"),
        ("o-scene-mesh", ["-o", str(nf / "mesh.ply")], "mesh.ply"),
        ("o-rig-image", ["-o", str(nf / "a.exr")], "a.exr"),
        ("o-rig", ["-o", str(nf / "cams.toml")], "cams.toml"),
        ("o-folder", ["-o", str(prev)], "folder"),
    ]:
        cases.append(Case(f"atlas-{name}", [*base, *args], [needle], keep=keep))
    cases.append(Case("atlas-o-foreign", ["light", "atlas", str(nf / "room.toml"), "--cameras",
                      str(nf / "cams.toml"), "-o", str(prev / "vals.json")], ["--overwrite"],
                      keep=keep))
    for name, needle in (("size", "size"), ("fov", "fov_deg"), ("look", "look")):
        cases.append(Case(f"atlas-rig-{name}", ["light", "atlas", str(nf / "room.toml"),
                          "--cameras", str(nf / f"rig_{name}.toml"), *free], [needle],
                          keep=keep))
    cases.append(Case("atlas-rig-too-big", ["light", "atlas", str(nf / "room.toml"),
                      "--cameras", str(nf / "rig_big.toml"), "--spp", "4096", *free],
                      ["--force"], keep=keep))
    return cases


def _show_cases(root: Path) -> list[Case]:
    ls = root / "ls"
    ls.mkdir()
    write_exr(ls / "map.exr", np.full((8, 16, 3), 0.5, np.float32))
    _huge_exr(ls / "map.exr", ls / "huge.exr")
    (ls / "good.json").write_text(json.dumps({**LIGHT, "hdr_map": {"file": "map.exr",
                                                                   "mapping": "equirect"}}))
    (ls / "hugemap.json").write_text(json.dumps({**LIGHT, "hdr_map": {
        "file": "huge.exr", "mapping": "equirect"}}))
    nan = float("nan")
    bad = {  # name: (table, key, value, the field the message must name)
        "sh-nan": ("sh", "coefficients", [[nan, 0.1, 0.1]] + [[0.1] * 3] * 3,
                   "sh.coefficients"),
        "sh-absurd": ("sh", "coefficients", [[1e300, 0.1, 0.1]] + [[0.1] * 3] * 3,
                      "sh.coefficients"),
        "sh-too-many": ("sh", "coefficients", [[0.1] * 3] * 400, "sh.coefficients"),
        "irr-inf": ("main_light", "irradiance", [float("inf"), 1, 1], "main_light.irradiance"),
        "irr-negative": ("main_light", "irradiance", [-1, 1, 1], "main_light.irradiance"),
        "lights-int": (None, "lights", 5, "lights"),
        "light-irr-nan": (None, "lights", [{"direction": [0, 1, 0], "irradiance": [nan] * 3}],
                          "lights[0].irradiance"),
        "light-dir-str": (None, "lights", [{"direction": "up", "irradiance": [1, 1, 1]}],
                          "lights[0].direction"),
        "timestamp-nan": (None, "timestamp", nan, "timestamp"),
    }
    prev = root / "ls_prev"
    prev.mkdir()
    (prev / "mine.png").write_bytes(b"a person's picture")
    os.symlink(root / "nowhere", prev / "dangling")
    keep = [ls, prev]
    out = ["-o", str(prev / "new.png")]
    cases = []
    for name, (table, key, value, field) in bad.items():
        d = json.loads(json.dumps(LIGHT))
        (d[table] if table else d)[key] = value
        f = ls / f"{name}.json"
        f.write_text(json.dumps(d))
        cases.append(Case(f"show-{name}", ["light", "show", str(f), *out],
                          [f"{f.name}: {field}:"], keep=keep))
    good = str(ls / "good.json")
    for name, o, needle in [
        ("over-json", ls / "good.json", "good.json"),
        ("over-map", ls / "map.exr", "map.exr"),
        ("foreign", prev / "mine.png", "--overwrite"),
        ("folder", prev, "folder"),
        ("dangling", prev / "dangling", "dangling"),
        ("under-dangling", prev / "dangling" / "x.png", "dangling"),
        ("ledger", prev / ".arlight-written.json", "record"),
    ]:
        cases.append(Case(f"show-o-{name}", ["light", "show", good, "-o", str(o)], [needle],
                          keep=keep))
    cases += [
        Case("show-huge-map", ["light", "show", str(ls / "hugemap.json"), *out], ["--force"],
             keep=keep),
        Case("show-huge-image", ["light", "show", str(ls / "huge.exr"), *out], ["--force"],
             keep=keep),
        Case("estimate-huge-image", ["light", "estimate", str(ls / "huge.exr"), "-o",
             str(prev / "l.json")], ["--force"], keep=keep),
        Case("estimate-foreign", ["light", "estimate", str(ls / "map.exr"), "-o",
             str(prev / "mine.png")], ["--overwrite"], keep=keep),
        Case("estimate-fov-inf", ["light", "estimate", str(ls / "map.exr"), "--kind",
             "fisheye", "--fov", "inf", "-o", str(prev / "l.json")], ["--fov"], keep=keep),
    ]
    return cases


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    root = tmp_path_factory.mktemp("contract_light")
    cases = (_import_cases(root) + _probeless_cases(root) + _atlas_cases(root)
             + _show_cases(root))
    for c in cases:
        c.max_rss_mb = MAX_RSS_MB
    failures = check(cases, clean_env(root))
    return cases, failures


def test_enough_generated_cases(ran):
    cases, _ = ran
    assert len(cases) >= 60
    assert len({c.id for c in cases}) == len(cases), "case ids must be unique"


def test_every_bad_input_exits_2_one_line_inputs_untouched(ran):
    """Bugs caught: an output replacing the input or a file it references (the XML, a mesh
    or map of the scene, the intrinsics/colour/depth of an RGB-D folder, the rig's images),
    a person's file replaced, NaN light data pictured with exit 0, ``"lights": 5`` ending in
    a TypeError, --vals 10^9 silently capped, sizes that reach a MemoryError, dangling
    symlinks and folders as -o ending in an internal error."""
    cases, failures = ran
    assert not failures, f"{len(failures)} of {len(cases)} cases:\n" + "\n".join(failures)
