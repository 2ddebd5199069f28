"""``import arlight`` before NumPy loads OpenBLAS with one thread (issue #32: its pool's
wake-ups cost ~15 ms a frame on loaded cores), unless the user chose a count."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

PROBE = """
import ctypes
{first}
import numpy
libs = sorted({{l.split()[-1] for l in open("/proc/self/maps") if "openblas" in l.lower()}})
lib = ctypes.CDLL(libs[0])
names = ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_",
         "openblas_get_num_threads")
fn = next((getattr(lib, n) for n in names if hasattr(lib, n)), None)
print(-1 if fn is None else fn())
"""


def blas_threads(first: str, env: dict[str, str]) -> int:
    """OpenBLAS' thread count in a fresh interpreter that runs ``first`` before NumPy."""
    out = subprocess.run([sys.executable, "-c", PROBE.format(first=first)], env=env,
                         capture_output=True, text=True, check=True).stdout
    n = int(out.strip())
    if n < 0:
        pytest.skip("this NumPy's OpenBLAS exports no get_num_threads")
    return n


@pytest.fixture
def clean_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if blas_threads("", env) == 1:
        pytest.skip("OpenBLAS loads with one thread here anyway (one core): nothing to test")
    return env


def test_importing_arlight_first_loads_openblas_single_threaded(clean_env):
    """Rejects an arlight that leaves OpenBLAS' default pool (one thread per core) in
    place: the control without arlight has more than one thread."""
    assert blas_threads("import arlight", clean_env) == 1


def test_a_users_thread_count_is_kept(clean_env):
    """Rejects an arlight that overrides ``OPENBLAS_NUM_THREADS`` when the user set it."""
    assert blas_threads("import arlight", {**clean_env, "OPENBLAS_NUM_THREADS": "2"}) == 2
