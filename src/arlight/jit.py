"""Dr.Jit / Mitsuba set-up shared by every tier: the variant and the wavefront width.

Core tier: imports nothing of arlight but :mod:`arlight.errors` and
:mod:`arlight.interrupts`, so :mod:`arlight.io`, :mod:`arlight.sampling` and the ground
truth can select the variant without loading :mod:`arlight.backend`.

* :func:`ensure_variant` — ``cuda_ad_rgb`` on a GPU, else ``llvm_ad_rgb`` on the CPU.
* :data:`MAX_LANES` — the most lanes (camera samples, record rays) one wavefront launch
  holds (memory bound).

``ARLIGHT_VARIANT`` overrides the choice. The LLVM variant needs an LLVM runtime >= 16
(``apt-get install -y libllvm19`` on Debian 12; ``DRJIT_LIBLLVM_PATH`` points Dr.Jit at a
specific ``libLLVM.so``).
"""

from __future__ import annotations

import os
import threading
from typing import TYPE_CHECKING

from arlight.errors import ArlightError
from arlight.interrupts import shielded, test_point

if TYPE_CHECKING:  # NumPy is imported where used: `arlight --help` loads no heavy module
    import numpy as np

_PREFERRED = ("cuda_ad_rgb", "llvm_ad_rgb")

MAX_LANES = 2_000_000
"""Lanes per wavefront launch (a pass of the path tracers, a batch of the ground truth)."""


def ensure_variant() -> str:
    """Set (once) and return the Mitsuba variant arlight renders with."""
    import mitsuba as mi

    current = mi.variant()
    if current is not None:
        return current
    wanted = os.environ.get("ARLIGHT_VARIANT")
    candidates = (wanted,) if wanted else _PREFERRED
    errors = []
    for name in candidates:
        if name not in mi.variants():
            errors.append(f"{name}: not built into this Mitsuba")
            continue
        test_point("variant")
        try:
            # shielded: the switch imports Python modules from native code (an interrupt
            # there came back as a RuntimeError, i.e. "bad input") and starts Dr.Jit's
            # worker threads, which must never receive SIGINT (see arlight.interrupts)
            with shielded():
                mi.set_variant(name)
                import drjit as dr

                dr.eval(mi.Float(1.0) + 1.0)  # fails here when the JIT backend is unusable
            return name
        except Exception as exc:  # the message says what is missing (CUDA, LLVM)
            errors.append(f"{name}: {exc}")
    raise ArlightError(
        "no usable Mitsuba variant. " + "; ".join(errors) +
        ". On Debian 12 install the LLVM runtime with `apt-get install -y libllvm19` "
        "(or set DRJIT_LIBLLVM_PATH to a libLLVM.so of version >= 16).")


ALIGN_BYTES = 64
"""Alignment of the NumPy buffers :func:`aligned` hands to Dr.Jit."""


FREEZE_LOCK = threading.RLock()
"""Held while a frozen Dr.Jit function (``dr.freeze``) records or replays, and by the
studio while it prepares a method on a thread of its own: a recording beside another
thread's kernels aborted the whole process (a CI run on 2026-12-03: the bounce probe's
recording in the studio's render thread while a preparation thread prefiltered a map;
Dr.Jit does not document freezing as safe alongside other threads). Re-entrant: a
preparation may call frozen functions itself."""

def aligned(a, dtype) -> np.ndarray:
    """``a`` as a C-contiguous NumPy array of ``dtype`` whose buffer starts on a 64-byte
    boundary, to build a Dr.Jit array from.

    Dr.Jit's LLVM backend reads a contiguous NumPy array in place and compiles the alignment
    it finds into the kernel (``align 64`` or ``align 1``). NumPy's buffers are 64-byte
    aligned or not depending on their size and the heap, so a kernel fed per-frame arrays
    (dic's records, whose count changes every frame) was compiled again whenever that
    changed: seconds on the CPU. Aligned inputs give one kernel.
    """
    import numpy as np

    src = np.asarray(a, dtype=dtype)
    raw = np.empty(src.nbytes + ALIGN_BYTES, np.uint8)
    start = (-raw.ctypes.data) % ALIGN_BYTES
    out = raw[start:start + src.nbytes].view(src.dtype).reshape(src.shape)
    out[...] = src
    return out


def columns(a, dtype) -> list[np.ndarray]:
    """The columns of an ``(N, k)`` array as :func:`aligned` 1-D arrays (build e.g. a
    ``mi.Point3f(*columns(p, np.float32))`` from them)."""
    import numpy as np

    a = np.asarray(a)
    return [aligned(a[:, c], dtype) for c in range(a.shape[1])]



def opaque(x: float):
    """``x`` as an opaque Dr.Jit ``Float`` scalar: read from memory by the kernel, not
    compiled into it, so one kernel serves every value (a moved camera, object or lamp,
    another spp or seed) without compiling again (seconds on the CPU)."""
    import drjit as dr
    import mitsuba as mi

    return dr.opaque(mi.Float, float(x))


def opaques(values) -> list:
    """:func:`opaque` of every element of ``values`` (flattened), e.g. a position's x, y, z."""
    import numpy as np

    return [opaque(x) for x in np.ravel(values)]

__all__ = ["ALIGN_BYTES", "aligned", "columns", "opaque", "opaques", "MAX_LANES", "ensure_variant"]
