"""`arlight live` refuses bad input with one line naming the field, exit 2, nothing written.

Rejects: a camera index that opens nothing being accepted (an empty loop that exits 0), an
unreadable video reaching the renderer, an unknown marker dictionary failing late (after
the method was prepared) or with a traceback, a recording that would replace the input
video, and a half-written recording or log after a refused run.
"""

from __future__ import annotations

import numpy as np
import pytest

from arlight.live import marker_video as mv
from tests.cli_invoke import MainRunner


def _live(*args):
    from arlight import cli

    return MainRunner().invoke(cli.app, ["live", *map(str, args), "--no-studio"])


@pytest.fixture
def base(clip):
    return [clip.scene, "--calib", clip.calib, "--marker", mv.MARKER, "-m", "dir"]


def test_help_explains_units_and_defaults():
    from arlight import cli

    r = MainRunner().invoke(cli.app, ["live", "--help"])
    assert r.exit_code == 0
    text = " ".join(r.output.split())
    for words in ("metres", "frames per second", "milliseconds", "dropped", "--example",
                  "default"):
        assert words in text, words


@pytest.mark.parametrize("args, field, words", [
    (["--camera", "97"], "--camera", "cannot open camera 97"),
    (["--video", "{bad}"], "--video", "cannot decode the video"),
    (["--video", "{missing}"], "--video", "no such folder or video file"),
    (["--video", "{frames}", "--camera", "0"], "--video", "exactly one of"),
    (["--video", "{frames}", "--marker", "charuco:5x7:0.04:0.03:DICT_NOPE"], "--marker",
     "DICT_NOPE"),
    (["--video", "{frames}", "-m", "no-such-method"], "method", "no-such-method"),
    (["--video", "{frames}", "--record", "{frames}/f0.png"], "--record", ""),
    (["--video", "{frames}", "--depth", "{missing}"], "--depth", "folder of depth images"),
    (["--video", "{frames}", "--depth", "{one_depth}"], "--depth", "1 depth images for 4"),
])
def test_bad_input_is_one_line_naming_the_field(base, clip, tmp_path, args, field, words):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"this is not a video" * 50)
    one = tmp_path / "one_depth"
    one.mkdir()
    from arlight.io.images import write_exr

    write_exr(one / "d0.exr", np.ones((240, 320), np.float32))
    subst = {"bad": bad, "missing": tmp_path / "nope.mp4", "frames": clip.frames,
             "one_depth": one}
    args = [a.format(**{k: str(v) for k, v in subst.items()}) for a in args]
    log = tmp_path / "log.jsonl"
    before = {p.name: p.read_bytes() for p in clip.frames.iterdir()}
    r = _live(*base, *args, "--log", log)
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    err = [x for x in r.stderr.splitlines() if x.startswith("error")]
    assert len(err) == 1 and field in err[0] and words in err[0], r.stderr
    assert not log.exists()
    assert {p.name: p.read_bytes() for p in clip.frames.iterdir()} == before


def test_recording_onto_the_input_video_is_refused(clip, tmp_path):
    video = tmp_path / "in.mp4"
    from arlight.io.images import read_ldr
    from arlight.sequence.video import encode

    encode(video, [read_ldr(clip.frames / "f0.png")] * 2, 10.0)
    data = video.read_bytes()
    r = _live(clip.scene, "--video", video, "--calib", clip.calib, "--marker", mv.MARKER,
              "--record", video)
    assert r.exit_code == 2 and "--record" in r.stderr and "input" in r.stderr, r.output
    assert video.read_bytes() == data


def test_a_video_recording_is_whole_and_may_be_replaced_by_a_rerun(base, clip, tmp_path):
    """The mp4 holds every composited frame, no staging folder is left next to it, and a
    second run may replace the recording it wrote (rejects a recorder that drops frames on
    its writer queue or leaves its PNG staging behind)."""
    from arlight.sequence.video import decode

    out = tmp_path / "rec.mp4"
    for _ in range(2):
        r = _live(*base, "--video", clip.frames, "--unpaced", "--record", out)
        assert r.exit_code == 0, r.output
        assert sum(1 for _ in decode(out)) == 4
        assert sorted(p.name for p in tmp_path.iterdir()) == [".arlight-written.json",
                                                               "rec.mp4"]
