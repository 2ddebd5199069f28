"""The one content hash (:mod:`arlight.content_hash`).

Rejects: an encoding that makes different inputs share a hash — a string and an object whose
``str`` is that string, large numpy arrays that differ only where ``str()`` elides them,
arrays of another shape or dtype with the same bytes, a path and its string, a list cut at
another place, ``1`` and ``1.0`` and ``True``; an encoding that depends on a dict's insertion
order; a silent ``str()`` of a type without a canonical encoding.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from arlight.content_hash import ByContent, ByName, content_hash, encode


def _old(*items) -> str:
    """The hasher ``sequence/job.py`` used before: ``json.dumps(default=str)``."""
    import hashlib

    d = hashlib.sha256()
    for x in items:
        if isinstance(x, np.ndarray):
            d.update(np.ascontiguousarray(x, np.float64).tobytes())
        else:
            d.update(json.dumps(x, sort_keys=True, default=str).encode())
    return d.hexdigest()[:16]


class _One:
    def __str__(self) -> str:
        return "1"


def test_inputs_that_collided_with_the_old_hasher_differ_now():
    big = np.zeros(5000)
    changed = big.copy()
    changed[2500] = 1.0  # str() shows "0. 0. 0. ... 0. 0. 0.": the change is elided
    pose = np.arange(16.0)
    pairs = [
        ({"m": big}, {"m": changed}),
        (pose.reshape(4, 4), pose.reshape(2, 8)),
        (np.ones(3, np.float32), np.ones(3, np.float64)),
    ]
    for a, b in pairs:
        assert _old(a) == _old(b)
        assert content_hash(a) != content_hash(b)
    # a string and an object whose str is that string: the old hasher could not tell them
    # apart; now the object has no encoding at all
    assert _old("1") == _old(_One())
    with pytest.raises(TypeError, match="_One"):
        content_hash(_One())
    # a path and its string: the caller says how a path counts
    assert _old("scene.toml") == _old(Path("scene.toml"))
    with pytest.raises(TypeError, match="ByContent"):
        content_hash(Path("scene.toml"))
    assert content_hash(ByName("scene.toml")) != content_hash("scene.toml")


def test_kinds_and_boundaries_are_tagged():
    values = [1, 1.0, True, "1", b"1", [1], (1,), {"1": 1}, {1: 1}, None, 0.0, -0.0,
              float("nan"), np.int64(1), np.float32(1), "", [], {}]
    encodings = [encode(v) for v in values]
    # everything distinct except list == tuple (both a sequence)
    assert len(set(encodings)) == len(values) - 1
    assert encode([1]) == encode((1,))
    assert content_hash(["ab"]) != content_hash(["a", "b"])
    assert content_hash([[1, 2], [3]]) != content_hash([[1], [2, 3]])
    assert content_hash("a", "b") != content_hash("ab")


def test_dicts_do_not_depend_on_order_and_values_round_trip():
    assert content_hash({"a": 1, "b": [2.5]}) == content_hash({"b": [2.5], "a": 1})
    assert content_hash(0.1 + 0.2) != content_hash(0.3)  # floats by repr, exactly
    assert content_hash(2**80) != content_hash(2**80 + 1)
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert content_hash(a) == content_hash(a.copy(order="F"))  # C-order bytes
    with pytest.raises(TypeError):
        content_hash(np.array([object()]))


def test_files_by_content(tmp_path):
    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    a.write_bytes(b"same")
    b.write_bytes(b"same")
    assert content_hash(ByContent(a)) == content_hash(ByContent(b))
    assert content_hash(ByName(a)) != content_hash(ByName(b))
    b.write_bytes(b"other")
    assert content_hash(ByContent(a)) != content_hash(ByContent(b))
