"""Layering rules: which arlight modules must not (even indirectly) load which others.

Each rule imports a module in a fresh interpreter, optionally runs a snippet that exercises
its lazy imports, and lists the arlight modules that ended up in ``sys.modules``. Add a
rule by adding a row to :data:`RULES`.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from dataclasses import dataclass

import pytest


@dataclass(frozen=True)
class Rule:
    """``importer`` (after running ``exercise``) must not load ``forbidden`` or its
    submodules; ``why`` is the reason, shown when the rule breaks."""

    importer: str
    forbidden: str
    why: str
    exercise: str = ""
    xfail: str = ""


# Renders a tiny photo so that imports done inside functions are loaded too.
_SYNTHESIZE = """
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize
world = parse_scene({"camera": {"resolution": [4, 3], "fov_y_deg": 40,
                                "look_at": {"origin": [0, 1, 2], "target": [0, 0, 0]}},
                     "shapes": [{"role": "real", "type": "rectangle", "size": [2, 2],
                                 "normal": [0, 1, 0]},
                                {"role": "virtual", "type": "sphere", "radius": 0.3,
                                 "material": {"type": "phong"}}],
                     "lights": [{"type": "constant", "radiance": 1.0}]})
synthesize(world, spp=2, use_cache=False)
"""

# Parses a scene with an SH light (its expansion into a map is imported lazily).
_SH_SCENE = """
from arlight.scene.load import parse_scene
parse_scene({"camera": {"resolution": [4, 3], "fov_y_deg": 40,
                        "look_at": {"origin": [0, 1, 2], "target": [0, 0, 0]}},
             "shapes": [], "lights": [{"type": "sh", "coefficients": [[1.0, 1.0, 1.0]]}]})
"""

_GROUND_TRUTH = ("the ground truth must share no code with the methods it grades "
                 "(docs: DESIGN.md, 'How we know it works')")

RULES = [
    Rule("arlight.synthetic", "arlight.methods", _GROUND_TRUTH, _SYNTHESIZE),
    Rule("arlight.synthetic", "arlight.backend.passes", _GROUND_TRUTH, _SYNTHESIZE),
    Rule("arlight.synthetic", "arlight.backend.camera_rays", _GROUND_TRUTH, _SYNTHESIZE),
    Rule("arlight.scene", "arlight.light",
         "scene files are read without the light-estimation package", _SH_SCENE),
]


@functools.cache
def _loaded_modules(importer: str, exercise: str) -> frozenset[str]:
    code = (f"import sys, json\nimport {importer}\n{exercise}\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('arlight'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    return frozenset(json.loads(out.stdout.strip().splitlines()[-1]))


@pytest.mark.parametrize(
    "rule", [pytest.param(r, marks=[pytest.mark.xfail(reason=r.xfail, strict=True)]
                          if r.xfail else []) for r in RULES],
    ids=[f"{r.importer}-not-{r.forbidden}" for r in RULES])
def test_import_rule(rule: Rule):
    """A module that must stay independent of another does not load it, directly or through
    anything it imports (also lazily, when ``exercise`` runs the code paths)."""
    loaded = _loaded_modules(rule.importer, rule.exercise)
    bad = sorted(m for m in loaded
                 if m == rule.forbidden or m.startswith(rule.forbidden + "."))
    assert not bad, f"{rule.importer} loads {bad}: {rule.why}"
