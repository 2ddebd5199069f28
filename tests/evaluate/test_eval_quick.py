"""`arlight eval --quick` as CI runs it: every registered method on every suite scene."""

import json

from arlight.cli import main
from arlight.evaluate.suite import list_scenes
from arlight.methods import available_methods


def test_eval_quick_default_runs_every_method_on_every_scene(tmp_path):
    out = tmp_path / "report"
    assert main(["eval", "--quick", "--repeats", "1", "--sweep", "", "-o", str(out)]) == 0
    cells = json.loads((out / "results.json").read_text())["cells"]
    expected = {(m, s) for m in available_methods() for s in list_scenes()}
    assert {(c["method"], c["scene"]) for c in cells} == expected
    assert not [c for c in cells if c.get("error")], "a cell failed"
    assert not [c for c in cells if c.get("skipped")], "a built-in method skipped a scene"
    assert all({"prepare", "trace"} <= set(c["stages"]) for c in cells)
    md = (out / "report.md").read_text()
    assert "Grand comparison" in md and "Stage times, ms" in md
    for m, s in expected:
        assert (out / "grids" / f"{s}__{m}.png").is_file()
