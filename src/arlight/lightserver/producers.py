"""Light producers for the server: callables ``frame index → NearFieldLight``.

- :class:`ReplayProducer` cycles through states computed beforehand (by the near-field
  pipeline, or loaded): the load test uses it so that the transport is measured at a fixed
  rate whatever the pipeline costs on the machine.
- :class:`SyntheticMovingLight` is a **synthetic source, not the Rohmer pipeline**: an
  analytic square lamp moving on a circle under the ceiling, cut into M equal sub-squares
  that are its exact VALs (uniform emitter: Rohmer Eq. 6 gives I_j = L·ΔA_j), and per
  virtual object the order-2 SH of the light bounced once by a diffuse floor (constant
  radiance from the lower hemisphere). It gives the server a light that changes every frame
  without cameras, for tests, demos and the load test.

The pipeline producer (radiance atlas → τ split → VALs → SH on fisheye frames) lives with
the near-field pipeline; see :mod:`arlight.lightserver.pipeline`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from arlight.errors import InputError
from arlight.nearfield.state import NearFieldLight
from arlight.sphere.sh import normalisation, sh_index


class ReplayProducer:
    """Cycle through precomputed states (frame i → states[i mod len])."""

    def __init__(self, states: Sequence[NearFieldLight]):
        if not states:
            raise InputError("needs at least one light state", field="states")
        self.states = list(states)

    def __call__(self, frame: int) -> NearFieldLight:
        return self.states[frame % len(self.states)]


def _grid(m: int) -> tuple[int, int]:
    """rows × cols = m with rows the largest divisor of m not above sqrt(m)."""
    rows = max(d for d in range(1, int(math.isqrt(m)) + 1) if m % d == 0)
    return rows, m // rows


def lower_hemisphere_sh(radiance: np.ndarray) -> np.ndarray:
    """Order-2 SH (9, 3) of a radiance that is ``radiance`` (RGB) from every direction with
    y < 0 and zero above (arlight.sphere convention, pole +Y).

    Exact: c_00 = L·2π·Y_00, c_10 = −L·π·N_10 (∫_{y<0} y dω = −π), and the l = 2, m = 0 term
    vanishes (∫_{y<0} (3y² − 1) dω = 0); every m ≠ 0 term vanishes by symmetry.
    """
    L = np.asarray(radiance, dtype=np.float64)
    sh = np.zeros((9, 3))
    sh[sh_index(0, 0)] = L * 2.0 * math.pi * normalisation(0, 0)
    sh[sh_index(1, 0)] = -L * math.pi * normalisation(1, 0)
    return sh


@dataclass
class SyntheticMovingLight:
    """An analytic moving lamp as VALs + floor bounce as SH (synthetic; see module doc).

    Attributes:
        vals: M, the number of VALs (sub-squares of the lamp).
        size: lamp side in m.
        radiance: lamp radiance, RGB W/(sr·m²) (Rohmer's Cornell ceiling light: 15).
        height: lamp height above the floor y = 0, m (the lamp faces down, -Y).
        orbit: radius of the lamp's circle around the world's Y axis, m.
        period: seconds of scene time per revolution.
        frame_dt: seconds of scene time per frame (1/18 s: Rohmer's server rate).
        floor_albedo: diffuse albedo of the floor that bounces the light (RGB).
        objects: virtual object centres (n_obj, 3) in m; one SH block each.
    """

    vals: int = 16
    size: float = 0.4
    radiance: tuple[float, float, float] = (15.0, 14.0, 12.0)
    height: float = 2.0
    orbit: float = 0.8
    period: float = 6.0
    frame_dt: float = 1.0 / 18.0
    floor_albedo: tuple[float, float, float] = (0.5, 0.45, 0.4)
    objects: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.1, 0.0]]))

    def __post_init__(self) -> None:
        if not 1 <= int(self.vals) <= 65536:
            raise InputError(f"{self.vals}: must be 1..65536", field="vals")
        for name in ("size", "height", "period", "frame_dt"):
            if not getattr(self, name) > 0:
                raise InputError(f"{getattr(self, name)}: must be > 0", field=name)
        self.objects = np.asarray(self.objects, dtype=np.float64).reshape(-1, 3)
        rows, cols = _grid(int(self.vals))
        # sub-square centres in the lamp's own (x, z) plane
        u = (np.arange(cols) + 0.5) / cols - 0.5
        v = (np.arange(rows) + 0.5) / rows - 0.5
        uu, vv = np.meshgrid(u * self.size, v * self.size)
        self._offsets = np.stack([uu.ravel(), np.zeros(uu.size), vv.ravel()], axis=1)
        self._cell_area = self.size * self.size / (rows * cols)

    def centre(self, frame: int) -> np.ndarray:
        """Lamp centre (3,) in m at ``frame``."""
        a = 2.0 * math.pi * frame * self.frame_dt / self.period
        return np.array([self.orbit * math.cos(a), self.height, self.orbit * math.sin(a)])

    def __call__(self, frame: int) -> NearFieldLight:
        positions = self.centre(frame) + self._offsets
        m = positions.shape[0]
        normals = np.tile([0.0, -1.0, 0.0], (m, 1))
        area = np.full(m, self._cell_area)
        intensity = np.asarray(self.radiance, dtype=np.float64)[None, :] * area[:, None]
        # floor irradiance below each object (Eq. 5 summed over the VALs, cos at both ends)
        sh = np.empty((len(self.objects), 9, 3))
        for i, obj in enumerate(self.objects):
            d = positions - np.array([obj[0], 0.0, obj[2]])
            r2 = np.einsum("ij,ij->i", d, d)
            cos = d[:, 1] / np.sqrt(r2)  # same angle at the floor and at the lamp
            E = (intensity * (cos * cos / r2)[:, None]).sum(axis=0)
            floor = np.asarray(self.floor_albedo) * E / math.pi
            sh[i] = lower_hemisphere_sh(floor)
        return NearFieldLight(positions=positions, normals=normals, intensity=intensity,
                              area=area, sh=sh)
