"""The import graph of arlight: tiers, plug-ins, the ground truth, no circles.

Two kinds of checks:

* **Static** (fast, every module): each module's ``import`` statements — also those inside
  functions — are read with :mod:`ast` and checked against the tiers of
  ``docs/architecture.md``::

      core      errors, interrupts, jit, cache, timing, stats, camera_response, layers, bounds,
                output_guard, staged_output, scene, io, sampling, sphere
      backend   backend
      engines   tracing, realtime, light, probeless, nearfield, synthetic (ground truth)
      contract  methods (package), methods.spec, methods.base, methods.fragments
      plug-ins  methods.<name>
      apps      cli, entry, demo, evaluate, layer_files, progressive, insert, sequence, studio,
                lightserver, live, importers, and the CLIs of the engine packages

  No module imports a higher tier; no plug-in imports another plug-in; only the ground
  truth itself, the synthetic data makers (:data:`GROUND_TRUTH_USERS`), ``evaluate`` and the CLI
  import ``arlight.synthetic``;
  ``sphere``, ``io`` and ``sampling`` never import ``backend``; no circle of imports between
  modules (a submodule importing its own package is not a circle).
* **Runtime** (:data:`RULES`): a module imported in a fresh interpreter, optionally after
  running a snippet that exercises its lazy imports, must not load another.
"""

from __future__ import annotations

import ast
import functools
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

# ------------------------------------------------------------------------------ static rules

SRC = Path(__file__).resolve().parents[1] / "src"

CORE, BACKEND, ENGINES, CONTRACT, PLUGINS, APPS = range(6)
TIER_NAMES = ("core", "backend", "engines", "method contract", "method plug-ins", "apps")
TIERS: dict[str, int] = {
    "arlight": CORE, "arlight.errors": CORE, "arlight.interrupts": CORE, "arlight.jit": CORE,
    "arlight.cache": CORE, "arlight.timing": CORE, "arlight.stats": CORE,
    "arlight.camera_response": CORE, "arlight.layers": CORE, "arlight.progress": CORE,
    "arlight.bounds": CORE, "arlight.output_guard": CORE, "arlight.staged_output": CORE,
    "arlight.scene": CORE, "arlight.io": CORE, "arlight.sampling": CORE,
    "arlight.sphere": CORE, "arlight.data": CORE,
    "arlight.backend": BACKEND,
    "arlight.tracing": ENGINES, "arlight.realtime": ENGINES, "arlight.light": ENGINES,
    "arlight.probeless": ENGINES, "arlight.nearfield": ENGINES, "arlight.synthetic": ENGINES,
    "arlight.denoise": ENGINES,
    "arlight.methods": CONTRACT, "arlight.methods.spec": CONTRACT,
    "arlight.methods.base": CONTRACT, "arlight.methods.fragments": CONTRACT,
    "arlight.cli": APPS, "arlight.cli_progress": APPS, "arlight.cli_options": APPS,
    "arlight.entry": APPS,
    "arlight.demo": APPS, "arlight.evaluate": APPS,
    "arlight.layer_files": APPS, "arlight.progressive": APPS, "arlight.insert": APPS,
    "arlight.sequence": APPS, "arlight.studio": APPS, "arlight.lightserver": APPS,
    "arlight.live": APPS,
    "arlight.importers": APPS, "arlight.light.cli": APPS, "arlight.probeless.cli": APPS,
    "arlight.nearfield.cli": APPS, "arlight.probeless.experiment": APPS,
}
"""Tier of a module: its longest listed prefix (``arlight.methods.<plug-in>`` not listed:
:data:`PLUGINS`)."""

GROUND_TRUTH = "arlight.synthetic"
GROUND_TRUTH_USERS = frozenset({"arlight.probeless.synthetic_rgbd",
                                "arlight.sequence.synthetic_video"})
"""Besides ``evaluate`` and the CLI, the makers of synthetic test data (RGB-D sequences,
videos with ground truth) render through the ground truth."""
NO_BACKEND = ("arlight.sphere", "arlight.io", "arlight.sampling")


def _within(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def tier_of(module: str) -> int:
    """The tier of ``module`` (an ``arlight`` module name)."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        name = ".".join(parts[:n])
        if name in TIERS:
            if TIERS[name] == CONTRACT and name == "arlight.methods" and len(parts) > 2:
                return PLUGINS
            return TIERS[name]
    raise AssertionError(f"{module} has no tier: add it to TIERS (docs/architecture.md)")


def scan(src: Path) -> dict[str, set[str]]:
    """``module -> arlight modules it imports`` for every ``arlight`` module under ``src``
    (imports anywhere in the file, relative ones resolved; ``from pkg import name`` is the
    submodule ``pkg.name`` when that exists, else ``pkg``)."""
    files: dict[str, tuple[Path, bool]] = {}
    for path in sorted((src / "arlight").rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        files[".".join(parts[:-1] if is_pkg else parts)] = (path, is_pkg)
    graph: dict[str, set[str]] = {}
    for module, (path, is_pkg) in files.items():
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                if node.level:
                    base = base[:len(base) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                names.add(target)
                names.update(f"{target}.{a.name}" for a in node.names)
        resolved = set()
        for name in names:
            while name and name not in files:
                name = name.rpartition(".")[0]
            if name and name != module:
                resolved.add(name)
        graph[module] = resolved
    return graph


def violations(graph: dict[str, set[str]]) -> list[str]:
    """Every broken rule of ``graph`` (module -> imported modules), one line each."""
    out = []
    for module, imported in sorted(graph.items()):
        t = tier_of(module)
        for dep in sorted(imported):
            if _within(module, dep):
                continue  # a submodule importing its own package
            d = tier_of(dep)
            if d > t:
                out.append(f"upward import: {module} ({TIER_NAMES[t]}) imports {dep} "
                           f"({TIER_NAMES[d]})")
            if t == d == PLUGINS and module.split(".")[2] != dep.split(".")[2]:
                out.append(f"plug-in imports a plug-in: {module} imports {dep} (move what "
                           "they share to realtime/, tracing/ or methods/fragments.py)")
            if (_within(dep, GROUND_TRUTH) and not _within(module, GROUND_TRUTH)
                    and module not in GROUND_TRUTH_USERS
                    and not _within(module, "arlight.evaluate") and module != "arlight.cli"):
                out.append(f"{module} imports the ground truth {dep}: {_GROUND_TRUTH}")
            if any(_within(module, p) for p in NO_BACKEND) and _within(dep, "arlight.backend"):
                out.append(f"{module} imports {dep}: sphere, io and sampling never import "
                           "the backend")
    out.extend(f"import circle: {' -> '.join(c)}" for c in _cycles(graph))
    return out


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One circle per strongly connected component of more than one module (Tarjan);
    edges from a submodule to its own package are left out."""
    edges = {m: sorted(d for d in deps if d in graph and not _within(m, d))
             for m, deps in graph.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    comps: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return comps


@functools.cache
def _graph() -> dict[str, set[str]]:
    return scan(SRC)


KNOWN: dict[str, str] = {}
"""Violations that are known and scheduled (prefix -> why); each must still occur, so the
entry goes when the import does."""


def test_the_import_graph_keeps_the_rules():
    """No upward import, no plug-in importing a plug-in, the ground truth imported only by
    its own tools, no backend under sphere/io/sampling, no import circle."""
    found = violations(_graph())
    bad = [v for v in found if not any(v.startswith(k) for k in KNOWN)]
    assert not bad, "\n".join(bad)
    gone = [k for k in KNOWN if not any(v.startswith(k) for v in found)]
    assert not gone, f"fixed, remove from KNOWN: {gone}"


def test_every_module_has_a_tier():
    for module in _graph():
        tier_of(module)


def _write(root: Path, module: str, text: str) -> None:
    path = root.joinpath(*module.split(".")).with_suffix(".py")
    path.parent.mkdir(parents=True, exist_ok=True)
    for parent in path.parents:
        if parent == root:
            break
        (parent / "__init__.py").touch()
    path.write_text(text)


@pytest.mark.parametrize(("module", "text", "expected"), [
    ("arlight.io.bad", "def f():\n    from arlight.methods.base import Layers\n",
     "upward import: arlight.io.bad (core) imports arlight.methods.base"),
    ("arlight.tracing.bad", "from ..methods import base\n",
     "upward import: arlight.tracing.bad (engines) imports arlight.methods.base"),
    ("arlight.methods.bad", "import arlight.methods.other\n",
     "plug-in imports a plug-in: arlight.methods.bad imports arlight.methods.other"),
    ("arlight.realtime.bad", "from arlight import synthetic\n",
     "arlight.realtime.bad imports the ground truth arlight.synthetic"),
    ("arlight.sampling.bad", "from arlight.backend import passes\n",
     "arlight.sampling.bad imports arlight.backend.passes"),
    ("arlight.tracing.bad", "from arlight.tracing import other\n",
     "import circle: arlight.tracing.bad -> arlight.tracing.other"),
])
def test_the_checker_rejects_a_broken_rule(tmp_path, module, text, expected):
    """A module added to a clean tree with one deliberately broken rule is reported."""
    _write(tmp_path, "arlight.methods.base", "")
    _write(tmp_path, "arlight.methods.other", "")
    _write(tmp_path, "arlight.synthetic", "")
    _write(tmp_path, "arlight.backend.passes", "")
    _write(tmp_path, "arlight.tracing.other", "import arlight.tracing.bad\n")
    assert not [v for v in violations(scan(tmp_path)) if "circle" not in v]
    _write(tmp_path, module, text)
    bad = violations(scan(tmp_path))
    assert any(v.startswith(expected) for v in bad), bad


def test_the_real_tree_with_an_added_upward_import_fails(tmp_path):
    """The checker on a copy of the real graph plus one upward edge (io -> methods)."""
    graph = {m: set(d) for m, d in _graph().items()}
    graph["arlight.io.images"].add("arlight.methods.base")
    assert any(v.startswith("upward import: arlight.io.images") for v in violations(graph))


# ----------------------------------------------------------------------------- runtime rules


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
