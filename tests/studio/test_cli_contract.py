"""``arlight studio`` under bad input (the shared contract of tests/cli_harness.py): every
case fails before the server starts — exit 2, one line naming the option or file, no
traceback, the scene folder and the save folder byte for byte as they were, bounded memory."""

from __future__ import annotations

import os
import shutil

import pytest

from arlight.demo import DEMO_DIR
from tests.cli_harness import Case, check, clean_env


def _cases(root):
    demo = root / "demo"
    shutil.copytree(DEMO_DIR, demo)
    scene = demo / "scene.toml"
    saves = root / "saves"
    saves.mkdir()
    (saves / "mine.toml").write_text("# the user's file\n")
    text = scene.read_text()
    variants = {
        "no-virtual.toml": text.replace('role = "virtual"', 'role = "real"'),
        "no-frame.toml": text.replace('[frame]\nimage = "frame.png"', ""),
        "garbage.toml": "camera = [[[",
        "missing-frame.toml": text.replace('image = "frame.png"', 'image = "nope.png"'),
    }
    for name, body in variants.items():
        (demo / name).write_text(body)
    (root / "afile").write_text("x")
    os.symlink(root / "nowhere", root / "dangling")
    (root / "trunc.exr").write_bytes(b"v/1\x01\x02")
    keep = [demo, saves]
    base = ["studio", str(scene), "--save-dir", str(saves), "--port", "0"]
    bad_options = [
        ("--port", "-1"), ("--port", "70000"), ("--port", "abc"), ("--port", "nan"),
        ("--resolution", "0x0"), ("--resolution", "abcx"), ("--resolution", "161x120"),
        ("--resolution", "64000x48000"), ("--resolution", "-320x-240"),
        ("--resolution", "nanxnan"),
        ("--method", "nope"), ("--method", ""),
        ("--format", "gif"), ("--quality", "0"), ("--quality", "101"), ("--quality", "nan"),
        ("--token", "short"), ("--token", "has spaces in it and is long"),
        ("--token", "x" * 300), ("--max-sessions", "0"), ("--max-sessions", "5000"),
        ("--max-sessions", "nan"), ("--host", "not a host"), ("--host", "256.1.1.1"),
    ]
    cases = [Case(f"studio{opt}={val[:12]}", [*base, opt, val], [opt], keep=keep)
             for opt, val in bad_options]
    cases += [
        Case("studio-save-dir-file", ["studio", str(scene), "--port", "0", "--save-dir",
                                      str(root / "afile")],
             ["afile"], keep=keep),
        Case("studio-save-dir-dangling", ["studio", str(scene), "--port", "0", "--save-dir",
                                          str(root / "dangling")], ["dangling"], keep=keep),
        Case("studio-gt-missing", [*base, "--ground-truth", str(root / "gt.exr")], ["gt.exr"],
             keep=keep),
        Case("studio-gt-truncated", [*base, "--ground-truth", str(root / "trunc.exr")],
             ["trunc.exr"], keep=keep),
        Case("studio-scene-missing", ["studio", str(demo / "nope.toml")], ["nope.toml"],
             keep=keep),
        *[Case(f"studio-scene-{name}", ["studio", str(demo / name), "--save-dir", str(saves),
                                        "--port", "0"], [name, "frame", "virtual"], keep=keep)
          for name in variants],
    ]
    return cases


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    root = tmp_path_factory.mktemp("studio-contract")
    cases = _cases(root)
    return cases, check(cases, clean_env(root))


def test_enough_cases(ran):
    cases, _ = ran
    assert len(cases) >= 30 and len({c.id for c in cases}) == len(cases)


def test_every_bad_studio_input_is_one_line_exit_2_and_changes_nothing(ran):
    cases, failures = ran
    assert not failures, f"{len(failures)} of {len(cases)} cases:\n" + "\n".join(failures)
