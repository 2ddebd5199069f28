"""`arlight eval --quick` as CI runs it: every registered method on every suite scene."""

import json

import pytest

from arlight.cli import main
from arlight.evaluate.suite import list_scenes
from arlight.methods import available_methods


@pytest.mark.slow  # ~2 min on 2 cores; each method's contract on a scene is in test_contract.py
def test_eval_quick_default_runs_every_method_on_every_scene(tmp_path, eval_cache,
                                                           monkeypatch):
    """The methods run with the defaults; the ground truth is the session's 64-spp photograph
    of each scene (64 single-sample batches, seed 1: the one ``test_ground_truth.py`` grades
    the methods against, rendered once for both) instead of eval's default 256 spp, whose
    quality nothing here looks at."""
    monkeypatch.setenv("ARLIGHT_CACHE", str(eval_cache))
    out = tmp_path / "report"
    assert main(["eval", "--quick", "--repeats", "1", "--sweep", "", "--gt-spp", "64",
                 "-o", str(out)]) == 0
    cells = json.loads((out / "results.json").read_text())["cells"]
    expected = {(m, s) for m in available_methods() for s in list_scenes()}
    assert {(c["method"], c["scene"]) for c in cells} == expected
    assert not [c for c in cells if c.get("error")], "a cell failed"
    # a method may skip only the scenes its capabilities exclude (dlpv/dir: diffuse only)
    from arlight.evaluate.suite import get_scene
    from arlight.methods import get_method

    allowed = {(m, s) for m, s in expected
               if get_method(m).spec.unsupported_reason(get_scene(s, quick=True).world)}
    skipped = {(c["method"], c["scene"]) for c in cells if c.get("skipped")}
    assert skipped == allowed, "a built-in method skipped a scene it supports"
    assert all("prepare" in c["stages"] and len(c["stages"]) >= 2
               for c in cells if not c.get("skipped"))
    md = (out / "report.md").read_text()
    assert "Grand comparison" in md and "Stage times, ms" in md
    for m, s in expected - allowed:
        assert (out / "grids" / f"{s}__{m}.png").is_file()
