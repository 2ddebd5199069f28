"""Mutation tests of the evaluation harness: with the code under test broken on purpose
(``tests/mutations.py``), the ground-truth tests (``tests/evaluate/test_ground_truth.py``)
must fail, and the ground-truth renderer must not notice the mutation.

Each mutation runs the ground-truth module in a subprocess (``pytest --mutation NAME -x``,
stopping at the first failure) on photographs rendered once, unmutated, by this process: the
subprocess gets a copy of them (``ARLIGHT_TEST_WARM_CACHE``), so a mutated run neither
renders ground truth nor writes into a cache another run reads. Which test caught each
mutation is printed and recorded as the ``caught_by`` property (``--junitxml``); the table in
``docs/testing.md`` comes from such a run. The photographs are the session's
(``eval_cache``): rendered once for this module and ``tests/evaluate/test_ground_truth.py``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from arlight.evaluate.suite import get_scene
from arlight.synthetic import synthesize
from tests.conftest import WARM_CACHE_ENV, area_light_scene, load
from tests.mutations import MUTATIONS, apply_mutation

ROOT = Path(__file__).resolve().parents[1]
GROUND_TRUTH_TESTS = "tests/evaluate/test_ground_truth.py"


@pytest.fixture(scope="module", autouse=True)
def _not_under_a_mutation(request):
    if request.config.getoption("--mutation"):
        pytest.skip("this session is itself mutated")


@pytest.fixture(scope="module")
def warm_cache(eval_cache, tmp_path_factory):
    """Every photograph the ground-truth tests read, rendered by this unmutated process: in
    the session's cache, where ``tests/evaluate/test_ground_truth.py`` has rendered them when
    it ran before in this session (rendered now otherwise). The mutated runs get a copy of its
    ground-truth photographs only (``synthetic/``: unmutated by construction, see
    :func:`test_mutations_leave_the_ground_truth_renderer_alone`), never the session's other
    caches."""
    from tests.evaluate.test_ground_truth import AGREE_SPP, BIAS_SPP, SCENES, photo

    for name in SCENES:
        scene = get_scene(name, quick=True)
        for spp in (AGREE_SPP, BIAS_SPP):
            photo(scene, spp, eval_cache)
    warm = tmp_path_factory.mktemp("ground-truth-warm")
    shutil.copytree(eval_cache / "synthetic", warm / "synthetic")
    return warm


def test_mutations_leave_the_ground_truth_renderer_alone():
    """Synthetic photographs are bitwise identical with every mutation applied: the
    mutations break the methods' seams, not the renderer that grades them."""
    world = load(area_light_scene(width=12, height=9))
    fields = ("frame", "frame_stderr", "ground_truth", "ground_truth_stderr", "mask")
    before = synthesize(world, spp=4, use_cache=False)
    for name in MUTATIONS:
        patcher = apply_mutation(name)
        try:
            after = synthesize(world, spp=4, use_cache=False)
        finally:
            patcher.undo()
        for f in fields:
            np.testing.assert_array_equal(getattr(after, f), getattr(before, f),
                                          err_msg=f"{name} changed the ground truth's {f}")


def failures(junit: Path) -> list[tuple[str, str]]:
    """(test id, first line of the failure message) of every failed or errored test."""
    out = []
    for case in ET.parse(junit).iter("testcase"):
        for bad in (*case.iter("failure"), *case.iter("error")):
            test = f"{case.get('classname', '').rsplit('.', 1)[-1]}::{case.get('name')}"
            out.append((test, (bad.get("message") or "").splitlines()[0] if bad.get("message")
                        else bad.tag))
    return out


@pytest.mark.parametrize("name", list(MUTATIONS))
def test_ground_truth_tests_catch_the_mutation(name, warm_cache, tmp_path, record_property):
    """At least one ground-truth test fails, by a failed assertion (not a crash)."""
    junit = tmp_path / "junit.xml"
    cmd = [sys.executable, "-m", "pytest", GROUND_TRUTH_TESTS, "--mutation", name, "-x", "-q",
           "-p", "no:cacheprovider", "-m", "not slow", f"--junitxml={junit}"]
    env = {**os.environ, WARM_CACHE_ENV: str(warm_cache)}
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    tail = proc.stdout[-3000:] + proc.stderr[-2000:]
    failed = failures(junit) if junit.is_file() else []
    assert proc.returncode == 1 and failed, f"{name} was not caught:\n{tail}"
    test, message = failed[0]
    assert message.startswith("AssertionError"), f"{name} made {test} crash:\n{tail}"
    record_property("caught_by", test)
    print(f"\n{name}: caught by {test}: {message}")
