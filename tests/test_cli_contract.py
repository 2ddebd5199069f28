"""The installed ``arlight`` command under bad input: generated malformed inputs for every
command, each run in a subprocess of the console script.

Contract checked for every case: the exit status (2 for bad input and usage errors), one
line on stderr naming the file or field at fault, no traceback, and a pre-existing output
(folder or light JSON) left byte for byte as it was, with no staging debris next to it.

Cases are generated: every leaf of a valid scene mutated to a wrong type or NaN, every
size/seed option given out-of-range and unparsable values, corrupt images and light JSON,
and output paths that cannot be written. Everything is detected before a render starts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from arlight.io.images import write_exr, write_png
from tests.cli_harness import ARLIGHT, Case, check, clean_env, previous_output
from tests.conftest import area_light_scene
from tests.scene.model_cases import model_cases


def _leaves(node, path=()):
    """(path, value) of every scalar/list-of-number leaf and every table of ``node``."""
    if isinstance(node, dict):
        yield path, node
        for k, v in node.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(node, list) and node and not all(isinstance(x, int | float) for x in node):
        for i, v in enumerate(node):
            yield from _leaves(v, (*path, i))
    else:
        yield path, node


def _set(d, path, value):
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value


def _field_text(path) -> str:
    out = ""
    for k in path:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out


def _wrong_values(value):
    """Values of the wrong type (and NaN for numbers) for a leaf."""
    if isinstance(value, bool):
        return [("str", "yes")]
    if isinstance(value, int | float):
        return [("str", "oops"), ("nan", float("nan")), ("list", [1, 2])]
    if isinstance(value, str):
        return [("num", 12345)]
    if isinstance(value, list):
        return [("str", "oops"), ("nan", [float("nan")] * len(value))]
    if isinstance(value, dict):
        return [("num", 7)]
    return []


def _build(root: Path) -> list[Case]:
    cases: list[Case] = []
    scene = area_light_scene(16, 12)
    good = root / "scene.json"
    good.write_text(json.dumps(scene))
    write_png(root / "frame.png", np.full((12, 16, 3), 90, np.uint8))

    # --- scene files: every leaf with a wrong type / NaN (validate, and render for some)
    n = 0
    for path, value in _leaves(scene):
        if not path:
            continue
        for tag, bad in _wrong_values(value):
            d = json.loads(json.dumps(scene))
            _set(d, path, bad)
            f = root / f"mut{n:03d}.json"
            f.write_text(json.dumps(d))
            fld = _field_text(path)
            if n % 7 == 0:  # some through render, with an existing output folder
                prev = previous_output(root, f"prev_mut{n:03d}")
                cases.append(Case(f"render-scene-{fld}-{tag}", ["render", str(f), "--spp", "1",
                                  "-o", str(prev)], [f.name, fld], keep=prev))
            else:
                cases.append(Case(f"validate-{fld}-{tag}", ["validate", str(f)], [f.name, fld]))
            n += 1

    # --- scene files that are not scene files
    raw = {"empty.json": b"", "garbage.json": b"{not json", "list.json": b"[1, 2]",
           "bad.toml": b"camera = [[[", "nul.json": b"\x00\x01\x02", "tab.toml": b"\t= 1"}
    for name, data in raw.items():
        (root / name).write_bytes(data)
        cases.append(Case(f"validate-raw-{name}", ["validate", str(root / name)], [name]))
    cases += model_cases(root)  # glTF / USD models and pbr materials (issue #34)
    cases.append(Case("validate-missing", ["validate", str(root / "nope.toml")], ["nope.toml"]))
    cases.append(Case("validate-folder", ["validate", str(root)], [root.name]))
    d = json.loads(json.dumps(scene))
    d["frame"] = {"image": "missing.png"}
    (root / "noframe.json").write_text(json.dumps(d))
    cases.append(Case("validate-missing-frame", ["validate", str(root / "noframe.json")],
                      ["missing.png"]))
    (root / "trunc.png").write_bytes((root / "frame.png").read_bytes()[:40])
    d["frame"] = {"image": "trunc.png"}
    (root / "truncframe.json").write_text(json.dumps(d))
    cases.append(Case("validate-truncated-frame", ["validate", str(root / "truncframe.json")],
                      ["trunc.png"]))
    d = json.loads(json.dumps(scene))
    d["camera"]["resolution"] = [40000, 30000]
    (root / "huge.json").write_text(json.dumps(d))
    prev = previous_output(root, "prev_huge")
    cases.append(Case("render-huge-resolution", ["render", str(root / "huge.json"), "-o",
                      str(prev)], ["--force"], keep=prev))

    # --- option values, per command (render/synth/demo/eval/light/methods)
    bad_values = {
        "--spp": ["0", "-1", "abc", "1e9", str(2**20 + 1)],
        "--seed": ["-1", str(2**32), "x"],
        "--max-depth": ["x", "1.5"],
    }
    for cmd in ("render", "synth"):
        for opt, vals in bad_values.items():
            for v in vals:
                prev = previous_output(root, f"prev_{cmd}{opt}{v}".replace("-", "_"))
                cases.append(Case(f"{cmd}-{opt}={v}", [cmd, str(good), opt, v, "-o", str(prev)],
                                  [opt], keep=prev))
    for opt, v in [("--time", "-5"), ("--time", "0"), ("--time", "nan"), ("--time", "inf"),
                   ("--frames", "-1"), ("--frames", "x"), ("--method", "nope"),
                   ("--option", "bogus"), ("--option", "reproject=maybe"), ("--bogus", "1")]:
        prev = previous_output(root, f"prev_prog{opt}{v}".replace("-", "_"))
        cases.append(Case(f"render-progressive-{opt}={v}", ["render", str(good), "--progressive",
                          "-m", "onepass", opt, v, "-o", str(prev)],
                          [opt.lstrip("-").split("=")[0] if opt != "--option" else "option"],
                          keep=prev))
    prev = previous_output(root, "prev_gt")
    cases.append(Case("render-progressive-missing-gt", ["render", str(good), "--progressive",
                      "-m", "onepass", "--frames", "1", "--ground-truth", str(root / "gt.exr"),
                      "-o", str(prev)], ["gt.exr"], keep=prev))
    for opt, v in [("--batches", "1"), ("--batches", "0"), ("--spp", "1")]:
        cases.append(Case(f"synth-{opt}={v}", ["synth", str(good), opt, v, "-o",
                          str(root / "s_out")], [opt.lstrip("-")]))
    for opt, v in [("--spp", "0"), ("-m", "nope"), ("--method", "")]:
        cases.append(Case(f"demo-{opt}={v}", ["demo", opt, v, "-o", str(root / "d_out")],
                          ["spp" if "spp" in opt else "nope" if v else "method"]))
    for opt, v in [("-m", "nope"), ("-s", "nope"), ("-m", ","), ("--spp", "0"),
                   ("--gt-spp", "1"), ("--repeats", "0"), ("--sweep", "a,b"), ("--sweep", "0"),
                   ("--seed", "-1"), ("--option", "bogus"), ("--option", "nope.x=1")]:
        cases.append(Case(f"eval-{opt}={v}", ["eval", opt, v, "-o", str(root / "e_out")],
                          [opt.lstrip("-") if opt.startswith("--") else v or "methods"]))
    for args, needle in [(["methods", "nope"], "nope"), (["nope"], "nope"),
                         (["render"], "scene"), (["light", "nope"], "nope"),
                         (["--bogus"], "bogus"), (["render", str(good), "extra"], "extra")]:
        cases.append(Case(f"usage-{'-'.join(args[:2])}", args, [needle]))

    # --- output paths that cannot be written
    (root / "afile").write_text("x")
    os.symlink(root / "nowhere", root / "dangling")
    foreign = root / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    for name, target, needle in [("is-file", root / "afile", "afile"),
                                 ("dangling", root / "dangling", "dangling"),
                                 ("under-file", root / "afile" / "sub", "afile"),
                                 ("foreign", foreign, "notes.txt"),
                                 ("scene-inside", root, "scene.json")]:
        for cmd in ("render", "synth"):
            cases.append(Case(f"{cmd}-out-{name}", [cmd, str(good), "-o", str(target)],
                              [needle], keep=foreign if name == "foreign" else None))
    cases.append(Case("eval-out-file", ["eval", "-m", "reference", "-s", "bunny-box", "-o",
                      str(root / "afile")], ["afile"]))

    # --- light inputs
    ramp = np.linspace(0.1, 2.0, 16 * 8 * 3, dtype=np.float32).reshape(8, 16, 3)
    write_exr(root / "env.exr", ramp)
    write_exr(root / "square.exr", np.ones((8, 8, 3), np.float32))
    neg = ramp.copy()
    neg[2, 3] = -1.0
    write_exr(root / "neg.exr", neg)
    write_png(root / "ldr.png", np.full((8, 16, 3), 128, np.uint8))
    (root / "trunc.exr").write_bytes((root / "env.exr").read_bytes()[:60])
    (root / "empty.exr").write_bytes(b"")
    (root / "cal_nan.json").write_text('{"K": [[NaN, 0, 4], [0, 5, 4], [0, 0, 1]], '
                                       '"size": [8, 8]}')
    (root / "cal_bad.yml").write_text("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: [\n")
    light_json = root / "light.json"
    light_json.write_text('{"previous": true}')  # an existing output that must survive
    e = ["light", "estimate"]
    o = ["-o", str(light_json)]
    for args, needle in [
        ([str(root / "missing.exr")], "missing.exr"),
        ([str(root / "square.exr"), "--kind", "equirect"], "2:1"),
        ([str(root / "ldr.png"), "--kind", "equirect"], "ldr.png"),
        ([str(root / "neg.exr")], "negative"),
        ([str(root / "trunc.exr")], "trunc.exr"),
        ([str(root / "empty.exr")], "empty.exr"),
        ([str(root / "env.exr"), "--kind", "cube"], "--kind"),
        ([str(root / "square.exr"), "--kind", "ball"], "--ball-center"),
        ([str(root / "square.exr"), "--kind", "ball", "--ball-center", "100,100",
          "--ball-radius", "3"], "not inside"),
        ([str(root / "square.exr"), "--kind", "ball", "--ball-center", "4,x",
          "--ball-radius", "3"], "--ball-center"),
        ([str(root / "square.exr"), "--kind", "ball", "--ball-center", "4,4",
          "--ball-radius", "nan"], "--ball-radius"),
        ([str(root / "square.exr"), "--kind", "fisheye", "--fisheye-calib",
          str(root / "cal_nan.json")], "cal_nan.json"),
        ([str(root / "square.exr"), "--kind", "fisheye", "--fisheye-calib",
          str(root / "cal_bad.yml")], "cal_bad.yml"),
        ([str(root / "square.exr"), "--kind", "fisheye", "--fov", "nan"], "--fov"),
        ([str(root / "square.exr"), "--kind", "fisheye", "--fov", "0"], "--fov"),
        ([str(root / "env.exr"), "--threshold", "nan"], "--threshold"),
        ([str(root / "env.exr"), "--threshold", "-1"], "--threshold"),
        ([str(root / "env.exr"), "--lights", "-1"], "--lights"),
        ([str(root / "env.exr"), "--lights", "1000000"], "--lights"),
        ([str(root / "env.exr"), "--sh-order", "-1"], "--sh-order"),
        ([str(root / "env.exr"), "--sh-order", "1000"], "--sh-order"),
        ([str(root / "env.exr"), "--height", "1000000"], "--height"),
        ([str(root / "env.exr"), "--height", "0"], "--height"),
        ([str(root / "env.exr"), "--layout", "nope"], "--layout"),
        ([str(root / "env.exr"), "--method", "nope"], "--method"),
    ]:
        cases.append(Case(f"light-estimate-{Path(args[0]).name}-{'-'.join(args[1:3])}",
                          [*e, *args, *o], [needle], keep=light_json))
    cases.append(Case("light-estimate-over-input", [*e, str(root / "env.exr"), "-o",
                      str(root / "env.exr")], ["env.exr"], keep=root / "env.exr"))
    cases.append(Case("light-estimate-out-dir", [*e, str(root / "env.exr"), "-o", str(root)],
                      ["folder"]))
    valid = {"format": "arlight.light_estimate", "version": 1,
             "main_light": {"direction_to_light": [0, 1, 0], "irradiance": [1, 1, 1]},
             "sh": {"order": 1, "quantity": "radiance", "basis": "arlight",
                    "coefficients": [[0.1, 0.1, 0.1]] * 4}, "lights": [],
             "timestamp": 0.0, "confidence": 1.0}
    mutations = {"unknown-key": ("colour", "red"), "unknown-sub": (("sh", "colour"), 1),
                 "dir-nan": (("main_light", "direction_to_light"), [float("nan"), 1, 0]),
                 "dir-str": (("main_light", "direction_to_light"), "up"),
                 "irr-short": (("main_light", "irradiance"), [1, 1]),
                 "sh-str": (("sh", "coefficients"), "abc"),
                 "sh-ragged": (("sh", "coefficients"), [[1, 2], [3]]),
                 "sh-count": (("sh", "coefficients"), [[0.1, 0.1, 0.1]] * 5),
                 "main-list": ("main_light", [1, 2, 3]), "lights-str": ("lights", "x"),
                 "light-bad": ("lights", [{"direction": [0, 1, 0]}]),
                 "confidence": ("confidence", 7.0), "confidence-str": ("confidence", "hi"),
                 "map-missing": ("hdr_map", {"file": "nomap.exr", "mapping": "equirect"}),
                 "format-only": (None, None)}
    for name, (key, value) in mutations.items():
        d = json.loads(json.dumps(valid))
        if key is None:
            d = {"format": "arlight.light_estimate"}
        elif isinstance(key, tuple):
            d[key[0]][key[1]] = value
        else:
            d[key] = value
        f = root / f"lj_{name}.json"
        f.write_text(json.dumps(d))
        png = previous_output(root, f"prev_show_{name}") / "composite.png"
        cases.append(Case(f"light-show-{name}", ["light", "show", str(f), "-o", str(png)],
                          [f.name], keep=png))
    for name, data in {"broken": "{broken", "array": "[1]", "empty": "", "arcore-short":
                       '{"environmentalHdrAmbientSphericalHarmonics": [1, 2]}'}.items():
        f = root / f"lj_{name}.json"
        f.write_text(data)
        cases.append(Case(f"light-show-{name}", ["light", "show", str(f), "-o",
                          str(root / "show.png")], [f.name]))
    cases += _insert_cases(root)
    for i, c in enumerate(cases):
        c.id = f"{i:03d}:{c.id}"
    return cases


def _insert_cases(root: Path) -> list[Case]:
    """``arlight insert`` with one bad input each (the rest valid): no marker in the photo,
    too few ChArUco corners, a calibration for another resolution, the object below the
    board, unreadable or missing light files, a bad marker, calibration, mesh or rig."""
    import cv2

    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02,
                                   cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    page = np.full((480, 640), 200, np.uint8)
    page[30:450, 170:470] = board.generateImage((300, 420), marginSize=0)
    write_png(root / "ins_photo.png", np.repeat(page[..., None], 3, axis=2))
    corner = np.full((480, 640), 200, np.uint8)
    corner[20:170, 20:170] = page[30:180, 170:320]  # two markers, one corner
    write_png(root / "ins_corner.png", np.repeat(corner[..., None], 3, axis=2))
    write_png(root / "ins_grey.png", np.full((480, 640, 3), 128, np.uint8))
    cal = {"K": [[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]], "size": [640, 480]}
    (root / "ins_cal.json").write_text(json.dumps(cal))
    (root / "ins_cal_big.json").write_text(json.dumps({**cal, "size": [1280, 960]}))
    (root / "ins_light_bad.json").write_text("{broken")
    (root / "ins_rig.toml").write_text("[[sun]]\ndirection = [0, 0, 0]\nirradiance = 1\n")
    (root / "ins_tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                      "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    good = {"photo": str(root / "ins_photo.png"), "--calib": str(root / "ins_cal.json"),
            "--marker": "charuco:5x7:0.04:0.02:DICT_6X6_250", "--light": "sun:0,1,0:2:0.2",
            "--object": str(root / "ins_tet.obj"), "--at": "0.1,0,0.14", "--scale": "0.02"}
    bad = [("no-marker", {"photo": str(root / "ins_grey.png")}, "marker"),
           ("few-corners", {"photo": str(root / "ins_corner.png")}, "corners"),
           ("calib-size", {"--calib": str(root / "ins_cal_big.json")}, "ins_cal_big.json"),
           ("calib-garbage", {"--calib": str(root / "cal_bad.yml")}, "cal_bad.yml"),
           ("below-plane", {"--at": "0.1,-0.05,0.14"}, "--at"),
           ("light-unreadable", {"--light": str(root / "ins_light_bad.json")},
            "ins_light_bad.json"),
           ("light-missing", {"--light": str(root / "nolight.hdr")}, "nolight.hdr"),
           ("light-rig", {"--light": str(root / "ins_rig.toml")}, "ins_rig.toml"),
           ("marker-dict", {"--marker": "charuco:5x7:0.04:0.02:DICT_NOPE"}, "DICT_NOPE"),
           ("marker-form", {"--marker": "charuco:5:0.04"}, "--marker"),
           ("object-missing", {"--object": str(root / "nomesh.obj")}, "nomesh.obj"),
           ("object-draco-glb", {"--object": str(root / "models" / "draco.glb")},
            "KHR_draco_mesh_compression"),  # written by model_cases (issue #34)
           ("object-usd-texture", {"--object": str(root / "models" / "mt.usda")},
            "inputs:file"),
           ("scale-nan", {"--scale": "nan"}, "--scale"),
           ("method-option", {"--option": "bogus=1"}, "bogus")]
    cases = []
    for name, change, needle in bad:
        args = {**good, **change}
        prev = previous_output(root, f"prev_insert_{name}".replace("-", "_"))
        argv = ["insert", args.pop("photo")]
        for k, v in args.items():
            argv += [k, v]
        cases.append(Case(f"insert-{name}", [*argv, "-o", str(prev)], [needle], keep=prev))
    return cases


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    root = tmp_path_factory.mktemp("contract")
    cases = _build(root)
    listing = sorted(p.name for p in root.iterdir())
    failures = check(cases, clean_env(root))
    return cases, failures, listing, root


def test_enough_generated_cases(ran):
    cases, *_ = ran
    assert len(cases) >= 100
    assert len({c.id for c in cases}) == len(cases), "case ids must be unique"


def test_every_bad_input_one_line_exit_2_no_output_change(ran):
    """Bugs caught: usage errors ending in a traceback (click not installed), light errors
    exiting 0, messages that wrap over lines or do not name the file/field, outputs touched
    by a failed run, staging folders left behind."""
    cases, failures, listing, root = ran
    assert not failures, f"{len(failures)} of {len(cases)} cases:\n" + "\n".join(failures)
    debris = [n for n in sorted(p.name for p in root.iterdir()) if n not in listing
              and n not in ("cache", "show.png")]
    assert not debris, debris


def test_bare_command_prints_help_and_exits_2():
    for args in ([], ["light"]):
        r = subprocess.run([ARLIGHT, *args], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "Usage" in r.stdout and "Traceback" not in r.stderr


def test_internal_error_is_one_line_exit_1_and_debug_shows_traceback(tmp_path):
    """An unexpected exception: one line and exit 1; ``--debug`` adds the traceback."""
    code = ("import sys; import arlight.cli as c\n"
            "@c.app.command('boom')\n"
            "def boom() -> None:\n    raise RuntimeError('kaput')\n"
            "sys.exit(c.main(sys.argv[1:]))\n")
    r = subprocess.run([sys.executable, "-c", code, "boom"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "kaput" in r.stderr
    r = subprocess.run([sys.executable, "-c", code, "--debug", "boom"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 1 and "Traceback" in r.stderr


def test_non_utf8_scene_file_is_bad_input(tmp_path):
    f = tmp_path / "latin1.toml"
    f.write_bytes(b"name = '\xe9\xff'\n")
    r = subprocess.run([ARLIGHT, "validate", str(f)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "latin1.toml" in r.stderr
