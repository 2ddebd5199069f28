"""Shared fixtures for the light tests: smooth synthetic maps and the bundled probe."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from arlight.sphere.envmap import equirect_directions

DATA = Path(__file__).resolve().parents[2] / "src" / "arlight" / "data" / "light"


def smooth_map(height: int = 64) -> np.ndarray:
    """A smooth, positive, coloured sky: brighter above, a soft lobe toward +X+Y."""
    d = equirect_directions(height)
    lobe = np.exp(4.0 * (d @ np.array([0.6, 0.64, 0.48]) - 1.0))
    base = 0.3 + 0.2 * d[..., 1]
    rgb = np.stack([base + 2.0 * lobe, base + 1.5 * lobe, base + 0.8 * lobe + 0.1 * d[..., 2]],
                   axis=-1)
    return rgb.astype(np.float32)


@pytest.fixture
def make_smooth():
    """The :func:`smooth_map` factory (height -> map)."""
    return smooth_map


@pytest.fixture
def smooth() -> np.ndarray:
    return smooth_map()


@pytest.fixture
def grace() -> np.ndarray:
    from arlight.io.images import read_linear

    return read_linear(DATA / "grace_latlong_256x128.hdr")
