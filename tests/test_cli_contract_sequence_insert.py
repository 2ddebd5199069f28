"""``arlight sequence`` and ``arlight insert`` under bad input: generated cases, each run in a
subprocess of the installed console script (:mod:`tests.cli_harness`).

Contract checked for every case: exit status 2, one ``error:`` line naming the file or option
at fault, no traceback, the inputs and a complete earlier output byte for byte as they were
with no file added (``keep``), and a bounded peak memory — a huge frame, photo or ChArUco
board is refused from its header or description, not allocated.

The sequence cases run with ``--restart`` onto a complete earlier sequence: the hostile
tester's case, where a truncated frame found after the old set was deleted cost the user
their previous result. Rejects: a restart that empties the folder before every frame is
decoded; frames checked lazily during the render; an output that is, contains or lies in an
input; a video that replaces a file arlight did not write; a NaN or absurd number accepted;
a board or resolution allocated before the cost is estimated.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from arlight.io.images import write_png
from arlight.output_guard import record_written
from tests.cli_harness import Case, check, clean_env
from tests.sequence.conftest import make_tiny

SMALL_RSS_MB = 1200
"""Peak memory of a case whose input asks for gigabytes: what the imports take, no more."""


def _huge_png(path: Path, width: int, height: int) -> Path:
    """A valid 1-bit grey PNG of ``width × height`` pixels, a few kB on disk (streamed)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    row = b"\0" * (1 + (width + 7) // 8)
    comp = zlib.compressobj(1)
    idat = b"".join(comp.compress(row) for _ in range(height)) + comp.flush()
    path.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0))
                     + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
    return path


def _earlier_sequence(root: Path, name: str) -> Path:
    """A complete earlier sequence output: header, frames, log, video, summary, ledger."""
    out = root / name
    (out / "frames").mkdir(parents=True)
    lines = []
    for i in range(4):
        rel = f"frames/{i:06d}.png"
        write_png(out / rel, np.full((24, 32, 3), 10 * i, np.uint8))
        digest = __import__("hashlib").sha256((out / rel).read_bytes()).hexdigest()
        lines.append(json.dumps({"index": i, "file": rel, "sha256": digest, "stats": {}}))
    (out / "frames.jsonl").write_text("\n".join(lines) + "\n")
    (out / "sequence.json").write_text(json.dumps({"format": "arlight-sequence/1",
                                                   "key": "an earlier job", "frames": 4}))
    (out / "sequence.mp4").write_bytes(b"\0\0\0\x18ftypisom earlier video")
    (out / "summary.json").write_text('{"frames": 4}')
    record_written([out / "sequence.mp4", out / "summary.json"])
    return out


def _frames_variant(tiny, root: Path, name: str, change) -> Path:
    """A copy of the tiny frames folder with ``change(folder)`` applied."""
    d = root / f"frames_{name}"
    shutil.copytree(tiny.frames, d)
    change(d)
    return d


def _sequence_cases(root: Path) -> list[Case]:
    tiny = make_tiny(root / "seq", n=4)
    inputs = tiny.folder

    def args(out: Path, frames: Path | None = None, *extra: str, poses: Path | None = None,
             restart: bool = True) -> list[str]:
        return ["sequence", str(tiny.scene), "--frames", str(frames or tiny.frames),
                "--poses", str(poses or tiny.poses), "--objects", str(tiny.objects), "-m",
                "reference", "--spp", "1", "-o", str(out), *(["--restart"] if restart
                                                              else []), *extra]

    cases: list[Case] = []
    n = 0

    def add(name: str, argv_for, needles: list[str], keep_extra=(), rss=None) -> None:
        nonlocal n
        prev = _earlier_sequence(root, f"prev_seq{n:02d}")
        n += 1
        c = Case(f"sequence-{name}", argv_for(prev), needles,
                 keep=[prev, inputs, *keep_extra])
        if rss:
            c.max_rss_mb = rss
        cases.append(c)

    # --- frames: every one must decode with the first one's size, before OUT is touched
    def truncate(i: int, keep: float):
        def f(d: Path) -> None:  # the header stays: the frame fails only when decoded
            p = d / f"f{i}.png"
            data = p.read_bytes()
            p.write_bytes(data[:int(len(data) * keep)])
        return f

    def replace(i: int, data: bytes):
        def f(d: Path) -> None:
            (d / f"f{i}.png").write_bytes(data)
        return f

    def other_size(d: Path) -> None:
        write_png(d / "f3.png", np.full((30, 40, 3), 90, np.uint8))

    def hdr_among(d: Path) -> None:
        from arlight.io.images import write_exr

        (d / "f3.png").unlink()
        write_exr(d / "f3.exr", np.ones((24, 32, 3), np.float32))

    for name, change, needle in [
        ("truncated-middle", truncate(2, 0.5), "f2.png"),
        ("truncated-last", truncate(3, 0.6), "f3.png"),
        ("truncated-first", truncate(0, 0.5), "f0.png"),
        ("empty-frame", truncate(1, 0), "f1.png"),
        ("garbage-frame", replace(2, b"this is not a png" * 20), "f2.png"),
        ("other-size", other_size, "f3.png"),
        ("hdr-among-ldr", hdr_among, "mixes HDR and LDR"),
    ]:
        d = _frames_variant(tiny, root, name, change)
        add(f"frames-{name}", lambda out, d=d: args(out, d), [needle], [d])
    empty = root / "frames_none"
    empty.mkdir()
    add("frames-empty-folder", lambda out: args(out, empty), ["no images"], [empty])
    clip = root / "clip.mp4"
    clip.write_bytes(b"\0\0\0\x18ftypmp42" + b"garbage" * 50)
    add("frames-bad-video", lambda out: args(out, clip), ["clip.mp4"], [clip])

    # --- poses and object motion
    def poses_file(name: str, text: str) -> Path:
        p = root / f"poses_{name}.txt"
        p.write_text(text)
        return p

    good = tiny.poses.read_text().splitlines()
    body = [ln for ln in good if ln.strip() and not ln.startswith("#")]
    for name, text, needle in [
        ("nan", "\n".join(body[:2] + [body[2].replace(body[2].split()[1], "nan", 1)]
                          + body[3:]), "line 3"),
        ("short", "\n".join(body[:3]), "4 frames"),
        ("quaternion", "\n".join(body[:3] + ["3 0 0 0 0 0 0 5"]), "quaternion"),
        ("absurd", "\n".join(body[:3] + ["3 1e9 0 0 0 0 0 1"]), "line 4"),
    ]:
        p = poses_file(name, text + "\n")
        add(f"poses-{name}", lambda out, p=p: args(out, poses=p), [f"{p.name}: {needle}"]
            if needle.startswith("line") else [needle], [p])
    kf = root / "keys_nan.toml"
    kf.write_text("[[camera]]\nframe = 0\nworld_from_camera = [[nan, 0, 0, 0], [0, 1, 0, 0], "
                  "[0, 0, 1, 0], [0, 0, 0, 1]]\n")
    add("keyframes-nan", lambda out: args(out, poses=kf), ["keys_nan.toml"], [kf])
    objs = root / "objects_nan.txt"
    objs.write_text("0 ball 0 0 nan 0 0 0 1\n3 ball 0 0 0 0 0 0 1\n")
    add("objects-nan", lambda out: [*args(out)[:7], str(objs), *args(out)[8:]],
        ["objects_nan.txt"], [objs])
    add("marker-huge-board", lambda out: [*args(out)[:5], "marker", *args(out)[6:],
                                          "--calib", str(root / "ins_cal.json"), "--marker",
                                          "charuco:100000x100000:0.04:0.02:DICT_6X6_250"],
        ["--marker"], rss=SMALL_RSS_MB)

    # --- options
    for opt, v in [("--spp", "0"), ("--fps", "nan"), ("--fps", "0"), ("--video", "avi"),
                   ("--split", "0"), ("--option", "nope=1")]:
        add(f"option{opt}={v}", lambda out, opt=opt, v=v: args(out, None, opt, v),
            [opt if opt != "-m" else "nope"] if opt != "--option" else ["nope"])
    add("split-not-progressive", lambda out: args(out, None, "-m", "dlpv", "--split", "2"),
        ["--split"])

    # --- bounds: the cost comes from the first frame's header, before anything is decoded
    big = root / "frames_huge"
    big.mkdir()
    _huge_png(big / "f0.png", 40000, 30000)
    for i in range(1, 4):
        shutil.copy(tiny.frames / f"f{i}.png", big / f"f{i}.png")
    add("huge-frame", lambda out: args(out, big), ["--force"], [big], rss=SMALL_RSS_MB)
    wide = root / "frames_wide"
    wide.mkdir()
    for i in range(4):
        _huge_png(wide / f"f{i}.png", 3200, 2400)
    add("frames-times-spp", lambda out: args(out, wide, "--spp", str(2**20)), ["--force"],
        [wide], rss=SMALL_RSS_MB)

    # --- outputs that are, hold or lie in an input, or are not a sequence's own
    for name, target, needles in [
        ("is-frames", tiny.frames, ["frames", "is the input"]),
        ("in-frames", tiny.frames / "out", ["inside the input folder"]),
        ("is-poses", tiny.poses, ["poses.txt", "is the input"]),
        ("holds-inputs", tiny.folder, ["contains the input"]),
    ]:
        cases.append(Case(f"sequence-out-{name}", args(target, restart=False), needles,
                          keep=inputs))
    foreign = root / "seq_foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    userframes = root / "seq_userframes"
    (userframes / "frames").mkdir(parents=True)
    (userframes / "frames" / "000000.png").write_bytes(b"my own picture")
    (root / "seq_afile").write_text("x")
    for name, target, needle, keep in [
        ("foreign", foreign, "notes.txt", foreign),
        ("user-frames", userframes, "000000.png", userframes),
        ("file", root / "seq_afile", "seq_afile", root / "seq_afile"),
    ]:
        for restart in (False, True) if name == "user-frames" else (name == "foreign",):
            cases.append(Case(f"sequence-out-{name}{'-restart' if restart else ''}",
                              args(target, restart=restart), [needle], keep=[keep, inputs]))
    # a video path that would replace a file arlight did not write, or an input
    unrecorded = _earlier_sequence(root, "prev_seq_unrecorded")
    (unrecorded / ".arlight-written.json").unlink()
    cases.append(Case("sequence-video-not-ours", args(unrecorded, restart=False),
                      ["sequence.mp4", "--restart"], keep=[unrecorded, inputs]))
    from arlight.io.images import read_ldr
    from arlight.sequence.video import encode

    video_in = encode(root / "input_clip.mp4", [read_ldr(f) for f in
                                                 sorted(tiny.frames.iterdir())], fps=4)
    linked = _earlier_sequence(root, "prev_seq_linked")
    (linked / "sequence.mp4").unlink()
    os.symlink(video_in, linked / "sequence.mp4")
    cases.append(Case("sequence-video-is-input", args(linked, video_in),
                      ["input_clip.mp4", "is the input"], keep=[linked, video_in, inputs]))
    return cases


def _insert_cases(root: Path) -> list[Case]:
    import cv2

    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02,
                                   cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    ins = root / "ins"
    ins.mkdir()
    page = np.full((480, 640), 200, np.uint8)
    page[30:450, 170:470] = board.generateImage((300, 420), marginSize=0)
    write_png(ins / "photo.png", np.repeat(page[..., None], 3, axis=2))
    cal = {"K": [[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]], "size": [640, 480]}
    (ins / "cal.json").write_text(json.dumps(cal))
    (root / "ins_cal.json").write_text(json.dumps(cal))
    (ins / "tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                 "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    (ins / "rig.toml").write_text("[[sun]]\ndirection = [0, 1, 0]\nirradiance = 2\n")
    (ins / "board.toml").write_text('type = "charuco"\nsquares = [5, 7]\nsquare_length = 0.04'
                                    '\nmarker_length = 0.02\ndictionary = "DICT_6X6_250"\n')
    huge = root / "ins_huge"
    huge.mkdir()
    _huge_png(huge / "huge.png", 40000, 30000)
    (huge / "cal.json").write_text(json.dumps({"K": cal["K"]}))
    good = {"photo": str(ins / "photo.png"), "--calib": str(ins / "cal.json"),
            "--marker": "charuco:5x7:0.04:0.02:DICT_6X6_250", "--light": "sun:0,1,0:2:0.2",
            "--object": str(ins / "tet.obj"), "--at": "0.1,0,0.14", "--scale": "0.02",
            "--spp": "1"}
    M = "charuco:5x7:{}:{}:DICT_6X6_250"
    bad = [
        ("board-huge", {"--marker": "charuco:100000x100000:0.04:0.02:DICT_6X6_250"},
         "--marker"),
        ("board-long", {"--marker": "charuco:2x1000000:0.04:0.02:DICT_6X6_250"}, "--marker"),
        ("aruco-id", {"--marker": "aruco:0.05:DICT_4X4_50:999"}, "--marker"),
        ("marker-nan", {"--marker": M.format("nan", "0.02")}, "--marker"),
        ("marker-tiny", {"--marker": M.format("0.04", "1e-12")}, "--marker"),
        ("at-nan", {"--at": "nan,0,0.1"}, "--at"),
        ("at-absurd", {"--at": "1e9,0,0"}, "--at"),
        ("scale-inf", {"--scale": "inf"}, "--scale"),
        ("rotate-zero-axis", {"--rotate": "0,0,0,30"}, "--rotate"),
        ("rotate-nan", {"--rotate": "0,1,0,nan"}, "--rotate"),
        ("color-nan", {"--color": "0.5,nan,0.5"}, "--color"),
        ("light-rotation-nan", {"--light-rotation": "nan"}, "--light-rotation"),
        ("light-scale-nan", {"--light-scale": "nan"}, "--light-scale"),
        ("light-scale-0", {"--light-scale": "0"}, "--light-scale"),
        ("plane-nan", {"--plane-size": "nan,1"}, "--plane-size"),
        ("box-nan", {"--box": "0,nan,0:0.1,0.1,0.1"}, "--box"),
        ("box-albedo-nan", {"--box": "0,0,0:0.1,0.1,0.1:nan,0,0"}, "--box"),
        ("sun-nan", {"--light": "sun:nan,1,0:2"}, "--light"),
        ("spp-bounds", {"--spp": str(2**20)}, "--force"),
        ("huge-photo", {"photo": str(huge / "huge.png"), "--calib": str(huge / "cal.json")},
         "--force"),
    ]
    cases = []
    for name, change, needle in bad:
        args = {**good, **change}
        prev = root / f"prev_insert_{name}"
        prev.mkdir()
        (prev / "scene.toml").write_text("# an earlier insert\n")
        (prev / ".arlight-output.json").write_text(json.dumps({"writer": "insert",
                                                               "files": ["scene.toml"]}))
        argv = ["insert", args.pop("photo")]
        for k, v in args.items():
            argv += [k, v]
        cases.append(Case(f"insert-{name}", [*argv, "-o", str(prev)], [needle],
                          keep=[prev, ins], max_rss_mb=SMALL_RSS_MB))
    # -o that is an input, or holds one
    for name, target, needles in [
        ("photo", ins / "photo.png", ["photo.png", "is the input"]),
        ("calib", ins / "cal.json", ["cal.json", "is the input"]),
        ("mesh", ins / "tet.obj", ["tet.obj", "is the input"]),
        ("light", ins / "rig.toml", ["rig.toml", "is the input"]),
        ("marker", ins / "board.toml", ["board.toml", "is the input"]),
        ("holds-inputs", ins, ["contains the input"]),
    ]:
        argv = ["insert", good["photo"], "--calib", good["--calib"], "--marker",
                str(ins / "board.toml"), "--light", str(ins / "rig.toml"), "--object",
                good["--object"], "--at", good["--at"], "--scale", good["--scale"],
                "-o", str(target)]
        cases.append(Case(f"insert-out-is-{name}", argv, needles, keep=ins))
    return cases


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    root = tmp_path_factory.mktemp("contract_seq_ins")
    cases = _insert_cases(root) + _sequence_cases(root)
    for i, c in enumerate(cases):
        c.id = f"{i:03d}:{c.id}"
    listing = sorted(p.name for p in root.iterdir())
    failures = check(cases, clean_env(root))
    return cases, failures, listing, root


def test_enough_generated_cases(ran):
    cases, *_ = ran
    assert len(cases) >= 60
    assert len({c.id for c in cases}) == len(cases), "case ids must be unique"
    assert {c.args[0] for c in cases} == {"sequence", "insert"}


def test_every_bad_input_exit_2_one_line_inputs_and_earlier_outputs_untouched(ran):
    """Bugs caught: ``--restart`` deleting the earlier sequence before a truncated frame is
    found; a frame folder or a photo decoded before its size is bounded; a ChArUco board of
    10¹⁰ corners built (MemoryError, exit 1); NaN accepted by ``--light-scale`` or
    ``--rotate``; an output folder that is the photo, the calibration, the poses file or the
    frames folder; a video replacing a file arlight did not write."""
    cases, failures, listing, root = ran
    assert not failures, f"{len(failures)} of {len(cases)} cases:\n" + "\n".join(failures)
    debris = [n for n in sorted(p.name for p in root.iterdir()) if n not in listing
              and n != "cache"]
    assert not debris, debris
