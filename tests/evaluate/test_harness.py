"""The harness and `arlight eval`: reports, per-cell failures, bad arguments."""

from __future__ import annotations

import json

import numpy as np
import pytest

import arlight.methods as registry
from arlight.cli import main
from arlight.errors import InputError
from arlight.evaluate.harness import EvalConfig, run_evaluation
from arlight.evaluate.report import write_report
from arlight.methods import Layers, register


def _broken(scene, settings) -> Layers:
    """A method that always raises (per-cell error reporting)."""
    raise RuntimeError("kaboom")


def _frame_only(scene, settings) -> Layers:
    """Returns the frame unchanged (ignores the virtual objects)."""
    f = scene.frame
    z = np.zeros_like(f)
    return Layers.assemble(f, z, z, np.zeros(f.shape[:2]), stats={"samples": 0})


@pytest.fixture(autouse=True)
def fake_methods():
    """Register two test methods for this module only (the registry is process-global)."""
    register("test-broken")(_broken)
    register("test-frame")(_frame_only)
    yield
    for name in ("test-broken", "test-frame"):
        registry._REGISTRY.pop(name, None)
        registry._DOCS.pop(name, None)


def config(cache, **kw) -> EvalConfig:
    base = dict(methods=["reference"], scenes=["bunny-box"], spp=4, gt_spp=16, repeats=1,
                cache_dir=cache)
    return EvalConfig(**{**base, **kw})


def test_failures_stay_in_their_cells(eval_cache, tmp_path):
    cfg = config(eval_cache, methods=["reference", "test-broken", "no-such-method",
                                      "test-frame"], scenes=["bunny-box", "no-such-scene"])
    res = run_evaluation(cfg)
    cells = {(c.scene, c.method): c for c in res.cells}
    assert len(cells) == 8
    ok = cells[("bunny-box", "reference")]
    assert ok.ok and ok.seconds > 0 and ok.stats["samples"] == 80 * 60 * 4
    assert 0 < ok.metrics["psnr"] < 100 and 0 < ok.metrics["flip"] < 1
    assert "kaboom" in cells[("bunny-box", "test-broken")].error
    assert "unknown method" in cells[("bunny-box", "no-such-method")].error
    assert all("unknown scene" in cells[("no-such-scene", m)].error for m in cfg.methods)
    # a method that ignores the object is worse than the reference on the changed region
    frame = cells[("bunny-box", "test-frame")]
    assert frame.metrics["changed_psnr"] < ok.metrics["changed_psnr"]
    paths = write_report(res, tmp_path / "rep")
    md = paths["markdown"].read_text()
    assert "kaboom" in md and "unknown scene" in md and "| reference | bunny-box |" in md
    assert (tmp_path / "rep" / "grids" / "bunny-box__reference.png").stat().st_size > 1000
    assert (tmp_path / "rep" / "errors" / "bunny-box__test-broken.txt").is_file()
    data = json.loads(paths["json"].read_text())
    assert {c["method"] for c in data["cells"]} == set(cfg.methods)


def test_cache_only_reports_missing_ground_truth(tmp_path):
    res = run_evaluation(config(tmp_path / "empty-cache", cache_only=True))
    assert len(res.cells) == 1 and "not cached" in res.cells[0].error


@pytest.mark.parametrize("kw", [dict(methods=[]), dict(repeats=0), dict(sweep_spp=[0]),
                                dict(cache_only=True, use_cache=False)])
def test_bad_configuration_raises_input_error(kw, tmp_path):
    with pytest.raises(InputError):
        config(tmp_path, **kw)


def test_eval_cli_quick_end_to_end(eval_cache, tmp_path, monkeypatch):
    monkeypatch.setenv("ARLIGHT_CACHE", str(eval_cache))
    out = tmp_path / "report"
    rc = main(["eval", "--quick", "-m", "reference,test-broken", "-s", "glass-ring",
               "--spp", "4", "--gt-spp", "16", "--repeats", "1", "--sweep", "1,4",
               "-o", str(out)])
    assert rc == 0
    for name in ("report.md", "index.html", "results.json", "results.csv",
                 "grids/glass-ring__reference.png", "plots/error_vs_spp.png",
                 "plots/error_vs_time.png"):
        assert (out / name).is_file(), name
    html = (out / "index.html").read_text()
    assert "kaboom" in html and "glass-ring" in html
    sweep = json.loads((out / "results.json").read_text())["cells"][0]["sweep"]
    assert [p["spp"] for p in sweep] == [1, 4] and sweep[1]["rmse"] < sweep[0]["rmse"]


def test_eval_cli_rejects_bad_arguments(tmp_path):
    assert main(["eval", "--sweep", "1,x", "-o", str(tmp_path)]) == 2
    assert main(["eval", "--repeats", "0", "-o", str(tmp_path)]) == 2
