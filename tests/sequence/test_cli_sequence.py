"""``arlight sequence`` end to end: outputs, bad input, interruption and resume.

Rejects: a run that starts (or creates its output folder) before checking that frames and
poses agree, that the video decodes and that the Ray cluster answers; a resumed run that
renders frames already done, or loses frames that were done; a resumed video that differs
from an uninterrupted run's; a folder of another job silently mixed with this one.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from arlight.sequence.store import LOG
from tests.sequence.conftest import ARLIGHT, cli, make_tiny


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _frames(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((out / "frames").glob("*.png"))}


def test_outputs_and_rerun_renders_nothing(tiny, full_run):
    s = _summary(full_run)
    assert (s["frames"], s["rendered"], s["resumed"]) == (tiny.n, tiny.n, 0)
    assert len(_frames(full_run)) == tiny.n
    assert (full_run / "sequence.mp4").stat().st_size > 0
    assert sorted(p.name for p in (full_run / "layers" / "000003").iterdir()) == [
        "composite.exr", "delta.exr", "mask.exr", "mixed.exr"]
    from arlight.sequence.video import probe

    assert probe(full_run / "sequence.mp4")[:2] == (tiny.n, (32, 24))
    before = _frames(full_run)
    rc, out, err = cli(tiny.args(full_run, "--layers"))
    assert rc == 0, err
    assert "0 rendered, 8 already done" in out
    assert _frames(full_run) == before


def _run_until(tiny, out: Path, frames_done: int, sig: int) -> int:
    """Start a run slowed to 0.15 s per frame, send ``sig`` once ``frames_done`` frames
    are logged; returns the number of frames logged after it stopped."""
    p = subprocess.Popen([ARLIGHT, *tiny.args(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         env={**__import__("os").environ, "ARLIGHT_TEST_FRAME_DELAY": "0.15"})
    log = out / LOG
    t0 = time.time()
    while time.time() - t0 < 120:
        if log.is_file() and len(log.read_text().splitlines()) >= frames_done:
            break
        if p.poll() is not None:
            break
        time.sleep(0.02)
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    want = 128 + sig if sig == signal.SIGINT else -sig
    assert p.returncode == want, err
    if sig == signal.SIGINT:
        assert "run the same command again" in err
    return len([x for x in log.read_text().splitlines() if x.strip()])


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_interrupted_run_resumes_only_missing_frames(tiny, full_run, tmp_path, sig):
    out = tmp_path / "out"
    done = _run_until(tiny, out, 3, sig)
    assert 3 <= done < tiny.n
    assert not (out / "sequence.mp4").exists() and not (out / "summary.json").exists()
    rc, _, err = cli(tiny.args(out))
    assert rc == 0, err
    s = _summary(out)
    assert (s["rendered"], s["resumed"]) == (tiny.n - done, done)
    assert _frames(out) == _frames(full_run)
    assert (out / "sequence.mp4").read_bytes() == (full_run / "sequence.mp4").read_bytes()


def test_torn_log_line_and_corrupt_frame_are_rendered_again(tiny, full_run, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(full_run, out)
    log = out / LOG
    lines = log.read_text().splitlines()
    log.write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:20])  # torn last line
    (out / "frames" / "000002.png").write_bytes(b"not a png")
    rc, _, err = cli(tiny.args(out, "--layers"))
    assert rc == 0, err
    assert (_summary(out)["rendered"], _summary(out)["resumed"]) == (2, tiny.n - 2)
    assert _frames(out) == _frames(full_run)


def test_bad_input_exits_2_and_writes_nothing(tiny, tmp_path):
    out = tmp_path / "out"
    short = tmp_path / "short.txt"
    short.write_text("\n".join(tiny.poses.read_text().splitlines()[:5]) + "\n")
    args = tiny.args(out)
    cases = {
        "poses count": [*args[:5], str(short), *args[6:]],
        "frames count": [*args, "--poses", str(tiny.poses)],  # replaced below
        "bad video": None,
        "unreachable ray": [*args, "--ray", "127.0.0.1:9"],
        "unknown option": [*args, "--option", "nope=1"],
        "unknown shape": None,
    }
    fewer = tmp_path / "fewer"
    fewer.mkdir()
    for f in sorted(tiny.frames.iterdir())[:6]:
        (fewer / f.name).write_bytes(f.read_bytes())
    cases["frames count"] = [args[0], args[1], "--frames", str(fewer), *args[4:]]
    bad = tmp_path / "clip.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"garbage" * 50)
    cases["bad video"] = [args[0], args[1], "--frames", str(bad), *args[4:]]
    objs = tmp_path / "o.txt"
    objs.write_text("0 teapot 0 0 0 0 0 0 1\n7 teapot 0 0 0 0 0 0 1\n")
    cases["unknown shape"] = [*args[:7], str(objs), *args[8:]]
    expect = {"poses count": "8 frames (0..7)",
              "frames count": "(8 lines) but the sequence has 6 frames",
              "bad video": "cannot decode the video", "unreachable ray": "cannot reach",
              "unknown option": "nope", "unknown shape": "teapot"}
    for name, a in cases.items():
        rc, _, err = cli(a)
        assert rc == 2, (name, err)
        assert expect[name] in err and len(err.strip().splitlines()) == 1, (name, err)
        assert not out.exists(), name


def test_another_job_in_the_folder_is_refused(tiny, full_run, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(full_run, out)
    before = _frames(out)
    rc, _, err = cli(tiny.args(out, "--layers", "--seed", "3"))
    assert rc == 2 and "another sequence job (different settings)" in err
    assert _frames(out) == before
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    rc, _, err = cli(tiny.args(foreign))
    assert rc == 2 and "notes.txt" in err


@pytest.mark.slow
def test_video_input_and_webm_output(tmp_path):
    from arlight.io.images import read_ldr
    from arlight.sequence.video import encode, probe

    t = make_tiny(tmp_path / "t", n=4)
    clip = encode(tmp_path / "in.mp4", [read_ldr(f) for f in sorted(t.frames.iterdir())],
                  fps=12)
    out = tmp_path / "out"
    rc, _, err = cli(["sequence", str(t.scene), "--frames", str(clip), "--poses",
                      str(t.poses), "-m", "reference", "--spp", "1", "--video", "mp4,webm",
                      "-o", str(out)])
    assert rc == 0, err
    assert probe(out / "sequence.webm") == (4, (32, 24), 12.0)
    assert probe(out / "sequence.mp4")[0] == 4
    assert np.asarray(read_ldr(out / "frames" / "000003.png")).shape == (24, 32, 3)


def test_video_frame_source_decodes_every_frame(tmp_path):
    from arlight.sequence.frames import FrameSource
    from arlight.sequence.video import encode

    frames = [np.full((24, 32, 3), 40 * i + 20, np.uint8) for i in range(5)]
    src = FrameSource(encode(tmp_path / "in.mp4", frames, fps=10))
    assert (src.count, src.size, src.fps, src.is_video) == (5, (32, 24), 10.0, True)
    got = list(src.frames({1, 3}))
    assert [f.index for f in got] == [1, 3]
    assert [int(np.median(f.codes)) for f in got] == pytest.approx([60, 140], abs=2)


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file()}


def test_restart_with_a_truncated_frame_leaves_the_earlier_sequence_untouched(
        tiny, full_run, tmp_path):
    """A complete earlier sequence, ``--restart`` with a frame truncated in the middle of the
    folder: exit 2 naming the frame, the earlier set byte for byte as it was, no file added.
    Rejects: a restart that empties the folder before every frame is decoded (the old one
    deleted everything, rendered frames 0–4, then failed on the truncated one)."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(full_run, out)
    before = _tree(out)
    frames = tmp_path / "frames"
    shutil.copytree(tiny.frames, frames)
    bad = frames / "f5.png"
    bad.write_bytes(bad.read_bytes()[: bad.stat().st_size // 2])
    args = tiny.args(out, "--restart", "--seed", "7")
    args[args.index("--frames") + 1] = str(frames)
    rc, _, err = cli(args)
    assert rc == 2 and "f5.png" in err and len(err.strip().splitlines()) == 1, err
    assert _tree(out) == before
    # a valid restart replaces it
    rc, out_text, err = cli(tiny.args(out, "--restart", "--seed", "7"))
    assert rc == 0, err
    assert f"{tiny.n} rendered, 0 already done" in out_text
    assert json.loads((out / "sequence.json").read_text())["key"] != \
        json.loads((full_run / "sequence.json").read_text())["key"]


def test_output_that_is_holds_or_lies_in_an_input_is_refused_naming_both(tiny, tmp_path):
    """Rejects: ``-o`` equal to the poses file or the frames folder, or inside the frames
    folder (files would be added to an input), accepted or refused without naming it."""
    for target, words in [(tiny.poses, "is the input"), (tiny.frames, "is the input"),
                          (tiny.frames / "out", "inside the input folder"),
                          (tiny.folder, "contains the input")]:
        before = _tree(tiny.folder)
        rc, _, err = cli(tiny.args(target, "--restart"))
        assert rc == 2 and words in err and str(target) in err, (target, err)
        assert _tree(tiny.folder) == before and not (tiny.frames / "out").exists()


def test_folder_of_other_pictures_named_frames_is_not_a_sequence(tiny, tmp_path):
    """Rejects: a folder whose top-level names look like a sequence's (``frames/``) taken
    for one, its pictures overwritten (or deleted by ``--restart``)."""
    out = tmp_path / "mine"
    (out / "frames").mkdir(parents=True)
    (out / "frames" / "000000.png").write_bytes(b"my own picture")
    (out / "frames" / "holiday.jpg").write_bytes(b"another")
    for extra in ((), ("--restart",)):
        rc, _, err = cli(tiny.args(out, *extra))
        assert rc == 2 and "holiday.jpg" in err and "not a sequence output" in err, err
        assert _tree(out) == {"frames/000000.png": b"my own picture",
                              "frames/holiday.jpg": b"another"}


def test_video_replaces_only_a_file_arlight_recorded(tiny, full_run, tmp_path):
    """The video and summary of a finished run are recorded in the output guard's ledger; a
    ``sequence.mp4`` that is not (someone's own file, or one edited since) is refused unless
    ``--restart``. Rejects: a rerun that overwrites any file named like the video."""
    import shutil

    from arlight.output_guard import LEDGER

    out = tmp_path / "out"
    shutil.copytree(full_run, out)
    assert (out / LEDGER).is_file()
    (out / "sequence.mp4").write_bytes(b"my edit of the video")
    rc, _, err = cli(tiny.args(out, "--layers"))
    assert rc == 2 and "sequence.mp4" in err and "--restart" in err, err
    assert (out / "sequence.mp4").read_bytes() == b"my edit of the video"


def test_frame_count_times_resolution_is_bounded_before_decoding(tiny, tmp_path):
    """A 40 000 × 30 000 first frame: refused from its header, naming --force, before it is
    decoded. Rejects: an estimate made after decoding the frame (30 GB) or none at all."""
    import shutil

    from tests.test_cli_contract_sequence_insert import _huge_png

    frames = tmp_path / "frames"
    shutil.copytree(tiny.frames, frames)
    _huge_png(frames / "f0.png", 40000, 30000)
    args = tiny.args(tmp_path / "out")
    args[args.index("--frames") + 1] = str(frames)
    rc, _, err = cli(args)
    assert rc == 2 and "--force" in err and "40000×30000" in err, err
    assert not (tmp_path / "out").exists()
