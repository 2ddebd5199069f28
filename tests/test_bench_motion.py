"""``benchmarks/bench_motion.py --write`` keeps the section's free-text notes.

Rejects the earlier ``--merge --write``, which rebuilt the section from the table and the
load line and dropped every note written below them by hand (they had to be restored after
each run), and a keeper that stacks the notes' heading once per run."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def B():
    sys.path.insert(0, str(BENCH))  # the script imports its sibling ``results``
    try:
        spec = importlib.util.spec_from_file_location("bench_motion", BENCH / "bench_motion.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(BENCH))


def _run(B, ratio: float) -> dict[str, dict[str, float]]:
    r = {"still": 0.1, "moving": 0.1 * ratio, "moving_mean": 0.1 * ratio, "pose": 0.01,
         "incremental": 1.0, "lamp": 0.12}
    return {"dvct": r}


def test_write_keeps_the_notes_and_drops_the_generated_merge_note(B):
    first = B.table({"dlpv": _run(B, 1.1)["dvct"], "dvct": _run(B, 1.6)["dvct"]}, 9,
                    "load average: 1.0", "0.2")
    old = ("# Benchmark results\n\n" + first
           + "\n\nRows of dvct from this run; dlpv kept from an earlier run (`--merge`)."
           + "\n\nThree quiet runs: dvct 1.33–1.69.\n\nLamp rows: opaque values (b6becb7)."
           + "\n\n## Next section\n\nother text\n")
    new = B.merged(B.table(_run(B, 1.2), 21, "load average: 2.0", "0.5"), old, ["dvct"])
    notes = B.earlier_notes(B.section_of(old))
    assert notes.startswith(B.NOTES_HEAD)
    assert "Three quiet runs: dvct 1.33–1.69." in notes
    assert "Lamp rows: opaque values (b6becb7)." in notes
    assert "Rows of dvct" not in notes and "other text" not in notes
    text = new + "\n\n" + notes
    assert "| dlpv |" in text and "| 1.20 |" in text  # kept row, new row
    # a second run keeps the same notes under one heading
    again = B.earlier_notes(B.section_of("# R\n\n" + text + "\n"))
    assert again == notes and again.count(B.NOTES_HEAD) == 1


def test_no_notes_without_a_section_or_after_the_load_line(B):
    assert B.earlier_notes(B.section_of("# Benchmark results\n")) == ""
    assert B.earlier_notes(B.table(_run(B, 1.0), 9, "load average: 1.0", "")) == ""
