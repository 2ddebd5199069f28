"""The light state of Rohmer's pipeline: VALs plus SH per virtual object (digest §5.3–5.4).

This is the whole of what travels from the light server to a client (Rohmer §4: only light
parameters, never images): M disc-shaped virtual area lights and, per virtual object, 9 RGB
SH coefficients of the indirect radiance seen from the object's centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arlight.errors import ArlightError

VAL_RECORD_BYTES = 32
"""Bytes of one VAL on Rohmer's wire (§4): position 12, octahedral normal 4, RGB 12, area 4."""
SH_BLOCK_BYTES = 9 * 3 * 4
"""Bytes of one object's SH block on the wire: 9 RGB float32 coefficients (108)."""
MAX_VALS = 256
"""Most VALs the ``nearfield`` method renders (its ``vals`` option's maximum; Rohmer uses
8 ≤ M ≤ 64) and the light server's wire accepts: a client's shadow maps and light loops
scale with M."""


@dataclass(frozen=True)
class NearFieldLight:
    """Virtual area lights and per-object SH indirect light (world frame, metres).

    Attributes:
        positions: (M, 3) float64, VAL centres in metres.
        normals: (M, 3) float64, unit VAL normals (the side that emits; a VAL is a
            one-sided Lambertian disc).
        intensity: (M, 3) float64, RGB radiant intensity along the normal I_j in W/sr
            (Rohmer Eq. 6: the sum over the cluster's texels of radiance × texel area).
        area: (M,) float64, disc area in m² (the cluster's summed texel area; disc radius
            sqrt(area/π)).
        sh: (n_obj, 9, 3) float64, order-2 real SH coefficients (arlight.sphere convention)
            of the indirect radiance at each virtual object's centre, W/(sr·m²).
        sequence: update number, increasing by one per server update (0 for a local estimate).
        timestamp: seconds since the epoch when the update was made (0.0 when unknown).
    """

    positions: np.ndarray
    normals: np.ndarray
    intensity: np.ndarray
    area: np.ndarray
    sh: np.ndarray
    sequence: int = 0
    timestamp: float = 0.0

    def __post_init__(self) -> None:
        m = np.shape(self.positions)[0] if np.ndim(self.positions) == 2 else -1
        checks = {"positions": (m, 3), "normals": (m, 3), "intensity": (m, 3), "area": (m,)}
        for name, shape in checks.items():
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if m < 0 or a.shape != shape:
                raise ArlightError(f"NearFieldLight.{name}: expected shape {shape} with M "
                                   f"from positions (M, 3), got {np.shape(getattr(self, name))}")
            if not np.all(np.isfinite(a)):
                raise ArlightError(f"NearFieldLight.{name}: values must be finite")
            object.__setattr__(self, name, a)
        sh = np.asarray(self.sh, dtype=np.float64)
        if sh.ndim != 3 or sh.shape[1:] != (9, 3) or not np.all(np.isfinite(sh)):
            raise ArlightError(f"NearFieldLight.sh: expected finite (n_obj, 9, 3), got "
                               f"{np.shape(self.sh)}")
        object.__setattr__(self, "sh", sh)
        if np.any(self.area < 0) or np.any(self.intensity < 0):
            raise ArlightError("NearFieldLight: VAL area and intensity must be >= 0")
        if m and not np.allclose(np.linalg.norm(self.normals, axis=1), 1.0, atol=1e-3):
            raise ArlightError("NearFieldLight.normals: VAL normals must be unit vectors")

    @property
    def count(self) -> int:
        """M, the number of VALs."""
        return int(self.positions.shape[0])

    @property
    def n_objects(self) -> int:
        """The number of virtual objects with an SH block."""
        return int(self.sh.shape[0])
