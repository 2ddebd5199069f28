"""Shared test helpers: small AR scenes built in code."""

from __future__ import annotations

import os
import shutil


def _single_threaded_blas() -> None:
    """Load NumPy's and SciPy's OpenBLAS with one thread each in the test process.

    OpenBLAS' default pool (one thread per core) spends its time waking and spinning on the
    small, tall matrices of the tests (``scipy.optimize.least_squares`` in the SoG fits: a
    thin SVD of 6912 × 9 per step): ``tests/realtime/test_sog.py`` took 120 s of CPU with
    it and 16 s without, with the same results. OpenBLAS reads ``OPENBLAS_NUM_THREADS``
    once, when the library loads; the variable is restored afterwards, so the subprocesses
    the tests start (the CLI, the interruption tests) get what a user gets (``import
    arlight`` before NumPy: one thread unless the variable is set; tests/test_blas_threads.py)."""
    previous = os.environ.get("OPENBLAS_NUM_THREADS")
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    try:
        import numpy  # noqa: F401
        import scipy.linalg  # noqa: F401 (SciPy's own OpenBLAS)
    finally:
        if previous is None:
            del os.environ["OPENBLAS_NUM_THREADS"]
        else:
            os.environ["OPENBLAS_NUM_THREADS"] = previous


_single_threaded_blas()

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from arlight.scene.load import parse_scene  # noqa: E402
from tests.mutations import mutation_session, pytest_addoption  # noqa: E402, F401 (plugin)

LOOK = {"origin": [0.0, 0.9, 2.2], "target": [0.0, 0.25, 0.0]}

WARM_CACHE_ENV = "ARLIGHT_TEST_WARM_CACHE"
"""A folder of ground-truth photographs rendered by an earlier, unmutated run
(``tests/test_mutations.py`` sets it): copied into the session's cache, so the photographs are
not rendered again and the original folder is never written."""


@pytest.fixture(scope="session")
def eval_cache(tmp_path_factory):
    """A synthetic-photo cache folder shared by the tests of a session: each photograph is
    rendered once per session (``tests/evaluate/test_ground_truth.py``,
    ``tests/test_mutations.py`` and ``tests/evaluate/test_eval_quick.py`` read the same
    ones)."""
    cache = tmp_path_factory.mktemp("arlight-cache")
    warm = os.environ.get(WARM_CACHE_ENV)
    if warm:
        shutil.copytree(warm, cache, dirs_exist_ok=True)
    return cache


def parsed_with_constant_frame(d: dict, value: float = 0.3):
    """The AR scene of the scene dict ``d`` with a constant camera frame of ``value``."""
    return with_constant_frame(parse_scene(d), value)

def diffuse(albedo) -> dict:
    return {"type": "diffuse", "albedo": albedo}


def real_room() -> list[dict]:
    """The real part of the small test scenes: a diffuse floor, a green back wall, a red box."""
    return [
        {"name": "floor", "role": "real", "type": "rectangle", "size": [3, 3],
         "normal": [0, 1, 0], "material": diffuse([0.7, 0.7, 0.6])},
        {"name": "wall", "role": "real", "type": "rectangle", "size": [3, 2],
         "transform": {"translate": [0, 1, -1]}, "material": diffuse([0.2, 0.6, 0.2])},
        {"name": "box", "role": "real", "type": "box", "size": [0.4, 0.4, 0.4],
         "transform": {"translate": [-0.5, 0.2, -0.2]}, "material": diffuse([0.8, 0.2, 0.1])},
    ]


def area_light_scene(width: int = 40, height: int = 30, virtual: bool = True) -> dict:
    """The real room, a virtual sphere, one area light."""
    shapes = real_room()
    if virtual:
        shapes.append({"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.25,
                       "transform": {"translate": [0.15, 0.25, 0.1]},
                       "material": {"type": "phong", "kd": 0.6, "ks": 0.2, "exponent": 20}})
    return {"camera": {"resolution": [width, height], "fov_y_deg": 45, "look_at": LOOK},
            "shapes": shapes,
            "lights": [{"type": "area", "size": [0.6, 0.6], "normal": [0, -1, 0],
                        "transform": {"translate": [0.3, 1.8, 0.4]}, "radiance": 12.0}]}


def env_mirror_scene(width: int = 40, height: int = 30) -> dict:
    """An env-lit floor with a real upright mirror and a virtual sphere seen in it."""
    from arlight.demo import DEMO_DIR

    return {"camera": {"resolution": [width, height], "fov_y_deg": 45, "look_at": LOOK},
            "shapes": [
                {"name": "floor", "role": "real", "type": "rectangle", "size": [3, 3],
                 "normal": [0, 1, 0], "material": diffuse(0.5)},
                {"name": "mirror", "role": "real", "type": "rectangle", "size": [1.6, 1.0],
                 "transform": {"translate": [0, 0.5, -0.8]},
                 "material": {"type": "mirror", "reflectance": 0.9}},
                {"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.25,
                 "transform": {"translate": [0.3, 0.25, 0.0]},
                 "material": diffuse([0.2, 0.3, 0.8])},
            ],
            "lights": [{"type": "envmap", "file": str(DEMO_DIR / "lebombo_512x256.hdr"),
                        "scale": 1.0, "rotation_deg": 30.0}]}


@pytest.fixture
def scene_dict():
    return area_light_scene()


def with_constant_frame(scene, value: float = 0.25):
    h, w = scene.camera.height, scene.camera.width
    return scene.with_frame(np.full((h, w, 3), value, np.float32))


def load(d: dict, tmp_path=None):
    return parse_scene(d, base_dir=tmp_path or ".")


@pytest.fixture(scope="session")
def point_world(eval_cache):
    """:func:`tests.shadow_worlds.shadow_world` under a point light: (scene, photograph)."""
    from tests.shadow_worlds import POINT, shadow_world

    return shadow_world(POINT, eval_cache)


@pytest.fixture(scope="session")
def area_world(eval_cache):
    """:func:`tests.shadow_worlds.shadow_world` under an area light: (scene, photograph)."""
    from tests.shadow_worlds import AREA, shadow_world

    return shadow_world(AREA, eval_cache)
