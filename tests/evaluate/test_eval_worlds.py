"""``arlight eval --worlds``: the CI-sized run of every piece (generated worlds, the
distribution tables, the equal-time ladder, the Pareto plots)."""

from __future__ import annotations

import json

from arlight import cli
from tests.cli_invoke import MainRunner


def test_eval_on_generated_worlds_reports_distributions_and_equal_time(tmp_path):
    out = tmp_path / "report"
    r = MainRunner().invoke(cli.app, [
        "eval", "--worlds", "training:2", "--width", 16, "-m", "onepass,dir,reference",
        "--gt-spp", 8, "--spp", 2, "--repeats", 1, "--sweep", "", "--ladder", "1,2",
        "-o", out])
    assert r.exit_code == 0, r.output
    data = json.loads((out / "results.json").read_text())
    assert set(data["scenes"]) == {"world-0", "world-1"}  # the suite is not run
    assert {s["split"] for s in data["scenes"].values()} == {"training"}
    rows = [d for d in data["distribution"] if d["group"] == "all"]
    assert {d["method"] for d in rows} == {"onepass", "dir", "reference"}
    for c in data["cells"]:
        if c["error"] or c["skipped"] or c["method"] == "onepass":
            continue
        ladder = data["onepass_ladders"][c["scene"]]
        fit = [p["spp"] for p in ladder if p["seconds"] <= c["seconds"]]
        assert c["metrics"]["onepass_at_time_spp"] == (max(fit) if fit else 0)
        # the ladder reaches past the slowest method of its world, or ends at its top spp
        slowest = max(x["seconds"] for x in data["cells"]
                      if x["scene"] == c["scene"] and not (x["error"] or x["skipped"]))
        assert ladder[-1]["seconds"] > slowest or ladder[-1]["spp"] == 2
    md = (out / "report.md").read_text()
    assert "## Over generated worlds" in md and "wins vs onepass" in md
    assert (out / "plots" / "pareto_all.png").is_file()
