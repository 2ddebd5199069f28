"""Which Dr.Jit kernels a render launches: the tool of the tests that a compiled kernel
serves every frame (a moved camera or object, another seed or spp)."""

from __future__ import annotations


def traced_kernels(render, min_ops: int = 100) -> set[str]:
    """Hashes of the kernels of ``min_ops`` operations or more (default the large ones: the
    tracers' and shaders', not the small reductions whose block size is the spp) that
    ``render()`` launches. Hashes identify the code, whether it came from Dr.Jit's memory or
    disk cache or was compiled."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        render()
    finally:
        history = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return {k["hash"] for k in history
            if k.get("type") == dr.KernelType.JIT and k.get("operation_count", 0) >= min_ops}
