"""The harness and `arlight eval`: reports, per-cell failures, bad arguments."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.cli import main
from arlight.errors import InputError
from arlight.evaluate.harness import EvalConfig, method_options, run_evaluation
from arlight.evaluate.report import write_report
from arlight.methods import Capabilities, Field, Layers, register, unregister


def _broken(scene, settings) -> Layers:
    """A method that always raises (per-cell error reporting)."""
    raise RuntimeError("kaboom")


SEEN_OPTIONS: list[dict] = []


def _frame_only(scene, settings) -> Layers:
    """Returns the frame unchanged (ignores the virtual objects); records its options."""
    SEEN_OPTIONS.append(dict(settings.options))
    f = scene.frame
    z = np.zeros_like(f)
    return Layers.assemble(f, z, z, np.zeros(f.shape[:2]), stats={"samples": 0})


def _unreachable(scene, settings) -> Layers:
    """Declares narrow capabilities; the harness must skip it instead of calling it."""
    raise AssertionError("a skipped cell ran")


FAKE = ("test-broken", "test-frame", "test-diffuse-only", "test-needs-depth")


@pytest.fixture(autouse=True)
def fake_methods():
    """Register test methods for this module only (the registry is process-global)."""
    register("test-broken")(_broken)
    register("test-frame", options={"gain": Field("float", 1.0, "unused")})(_frame_only)
    register("test-diffuse-only", capabilities=Capabilities(materials={"diffuse"}))(
        _unreachable)
    register("test-needs-depth", capabilities=Capabilities(needs_depth=True))(_unreachable)
    yield
    for name in FAKE:
        unregister(name)


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
    # stage times, Franke Tables 5.2/5.6 shape: a row per scene × method, a column per stage
    assert {"prepare", "setup", "trace", "assemble"} <= set(ok.stages)
    # prepare runs once per world; the other stages are those of the median frame
    assert sum(v for k, v in ok.stages.items() if k != "prepare") <= ok.seconds
    header, rows = data["stage_table_ms"]["header"], data["stage_table_ms"]["rows"]
    assert header[:2] == ["scene", "method"] and header[-2:] == ["Σ frame stages", "frame"]
    assert header[2:4] == ["prepare", "setup"] and "trace" in header
    ref_row = next(r for r in rows if r[:2] == ["bunny-box", "reference"])
    assert float(ref_row[header.index("trace")]) == pytest.approx(ok.stages["trace"] * 1e3,
                                                                   abs=0.01)
    assert "## Stage times, ms" in md and "| bunny-box | reference | " in md
    assert "Stage times, ms" in paths["html"].read_text()


def test_cells_a_method_cannot_handle_are_skipped_with_reason(eval_cache, tmp_path):
    """A method whose capabilities exclude the scene (glass-ring has glass and a rough
    conductor; no depth) is skipped, with the reason in every report format, and the other
    methods still run. Bug caught: the harness calls the method anyway (the cell errors or
    crashes), or drops the reason so the report shows an empty row."""
    cfg = config(eval_cache, methods=["test-diffuse-only", "test-needs-depth", "test-frame"],
                 scenes=["glass-ring"])
    res = run_evaluation(cfg)
    cells = {c.method: c for c in res.cells}
    assert not [c.error for c in res.cells if c.error]
    assert cells["test-frame"].ok and not cells["test-frame"].skipped
    only = cells["test-diffuse-only"].skipped
    assert "does not support material type glass, roughconductor" in only
    assert "needs a depth image" in cells["test-needs-depth"].skipped
    assert not any(c.ok for c in (cells["test-diffuse-only"], cells["test-needs-depth"]))
    paths = write_report(res, tmp_path / "rep")
    md, html = paths["markdown"].read_text(), paths["html"].read_text()
    assert f"skipped: {only}" in md and "class='skip'" in html
    data = json.loads(paths["json"].read_text())
    assert {c["method"]: c["skipped"] for c in data["cells"]}["test-diffuse-only"] == only
    assert "skipped" in paths["csv"].read_text().splitlines()[0]
    assert not (tmp_path / "rep" / "grids" / "glass-ring__test-diffuse-only.png").exists()


def test_a_scene_every_method_skips_renders_no_ground_truth(tmp_path):
    """Bug caught: the harness renders (and caches) a ground truth nobody uses."""
    cfg = config(tmp_path / "cache", methods=["test-needs-depth"], scenes=["red-paper"])
    res = run_evaluation(cfg)
    assert res.cells[0].skipped and not res.cells[0].error
    assert not (tmp_path / "cache").exists()


def test_options_go_to_the_methods_that_declare_them():
    """``method.key`` reaches one method, a bare ``key`` every method declaring it, the
    qualified form wins. Bug caught: a bare option sent to every method (reference would
    reject it), applied to the wrong method, or an unknown key silently ignored."""
    out = method_options(["reference", "onepass"], {"reproject": "false",
                                                    "onepass.mode": "twopass"})
    assert out == {"reference": {}, "onepass": {"reproject": "false", "mode": "twopass"}}
    out = method_options(["onepass"], {"onepass.reproject": "false", "reproject": "true"})
    assert out["onepass"]["reproject"] == "false"
    with pytest.raises(InputError, match="no evaluated method has option 'reproject'.*"
                                         "reference: sampler, replicas"):
        method_options(["reference"], {"reproject": "false"})
    with pytest.raises(InputError, match="no option 'bogus'.*env_mode"):
        method_options(["onepass"], {"onepass.bogus": "1"})
    with pytest.raises(InputError, match="not evaluated"):
        method_options(["reference"], {"onepass.reproject": "false"})
    with pytest.raises(InputError, match="options.reproject"):
        method_options(["onepass"], {"onepass.reproject": "maybe"})


def test_options_reach_the_method_converted(eval_cache):
    """Bug caught: EvalConfig.options never reach RenderSettings.options, or arrive as the
    command line's strings instead of the declared kind."""
    SEEN_OPTIONS.clear()
    run_evaluation(config(eval_cache, methods=["test-frame"], options={"gain": "2"}))
    assert SEEN_OPTIONS and all(o == {"gain": 2.0} for o in SEEN_OPTIONS)


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
    # bunny-box: diffuse, so 4 spp beats 1 spp on every seed (glass-ring's caustic fireflies
    # made the sweep's order a coin flip against a 16-spp ground truth)
    rc = main(["eval", "--quick", "-m", "reference,test-broken", "-s", "bunny-box",
               "--spp", "4", "--gt-spp", "16", "--repeats", "1", "--sweep", "1,4",
               "-o", str(out)])
    assert rc == 0
    for name in ("report.md", "index.html", "results.json", "results.csv",
                 "grids/bunny-box__reference.png", "plots/error_vs_spp.png",
                 "plots/error_vs_time.png"):
        assert (out / name).is_file(), name
    html = (out / "index.html").read_text()
    assert "kaboom" in html and "bunny-box" in html
    sweep = json.loads((out / "results.json").read_text())["cells"][0]["sweep"]
    assert [p["spp"] for p in sweep] == [1, 4] and sweep[1]["rmse"] < sweep[0]["rmse"]


def test_eval_cli_rejects_bad_arguments(tmp_path, capsys):
    assert main(["eval", "--sweep", "1,x", "-o", str(tmp_path)]) == 2
    assert main(["eval", "--repeats", "0", "-o", str(tmp_path)]) == 2
    # an option no evaluated method has fails before anything renders
    assert main(["eval", "-m", "reference", "--option", "reproject=false",
                 "-o", str(tmp_path / "r")]) == 2
    assert "reproject" in capsys.readouterr().err and not (tmp_path / "r").exists()
    assert main(["eval", "-m", "onepass", "--option", "onepass.reproject", "-o",
                 str(tmp_path / "r")]) == 2


def test_stage_times_come_from_the_median_run():
    """The stage table shows one real run, so its stages add up to no more than the median
    total. Bug caught: per-stage medians from different runs, whose sum can exceed the
    reported time (seen: Σ stages 74.75 ms > total 73.99 ms)."""
    from arlight.evaluate.harness import _median_run_stages

    seconds = [0.30, 0.10, 0.20, 0.25]
    runs = [{"prepare": 0.05, "trace": 0.24}, {"prepare": 0.01, "trace": 0.08},
            {"prepare": 0.09, "trace": 0.10}, {"prepare": 0.02, "trace": 0.22}]
    stages = _median_run_stages(seconds, runs)
    assert stages == runs[2] and sum(stages.values()) <= 0.20
