"""The one compositing equation every method shares.

Differential rendering (Debevec 1998; Kán Eq. 2.20; Franke Eq. 3.3):

    I_f = M ⊙ I_m + (1 − M) ⊙ (I_c + (I_m − I_r))

with ``mixed = I_m``, ``delta = I_m − I_r`` and ``background = I_c``. The delta is added
as one term, so a zero delta leaves the background bit-exact.
"""

from __future__ import annotations

import numpy as np


def composite(background: np.ndarray, mixed: np.ndarray, delta: np.ndarray,
              mask: np.ndarray) -> np.ndarray:
    """Composite virtual pixels over the relit background.

    Args:
        background: camera frame ``I_c`` as linear radiance, ``(H, W, 3)``.
        mixed: radiance of the real proxy plus virtual objects ``I_m``, ``(H, W, 3)``.
        delta: change of the real scene caused by the virtual objects, ``(H, W, 3)``.
        mask: virtual-object coverage ``M`` in [0, 1], ``(H, W)`` or ``(H, W, 1)``.

    Returns:
        ``(H, W, 3)`` linear radiance in the dtype of ``background`` promoted with the others.
        Pixels where ``M == 0`` and ``delta == 0`` equal ``background`` exactly.
    """
    m = np.asarray(mask)
    if m.ndim == 2:
        m = m[..., None]
    if background.shape != mixed.shape or background.shape != delta.shape:
        raise ValueError(f"shape mismatch: background {background.shape}, mixed {mixed.shape},"
                         f" delta {delta.shape}")
    if m.shape[:2] != background.shape[:2]:
        raise ValueError(f"mask shape {m.shape[:2]} does not match image {background.shape[:2]}")
    out_type = np.result_type(background, mixed, delta, m)
    relit = np.add(background, delta, dtype=out_type)
    covered = np.flatnonzero(m[..., 0] > 0)
    if covered.size:  # blend the covered pixels only (uncovered ones never read mixed)
        flat = relit.reshape(-1, relit.shape[-1])
        mc = m.reshape(-1, 1)[covered].astype(out_type, copy=False)
        flat[covered] = mc * mixed.reshape(flat.shape)[covered] + (1.0 - mc) * flat[covered]
    return relit
