"""Image input/output: LDR and HDR frames, EXR layers, atomic writes."""

from arlight.io.images import (
    atomic_write,
    read_hdr,
    read_ldr,
    read_linear,
    write_exr,
    write_png,
)

__all__ = ["atomic_write", "read_hdr", "read_ldr", "read_linear", "write_exr", "write_png"]
