"""The denoiser's method options, shared by every method that produces Monte Carlo noise
(with ``delta``, the form of the real pixels' change, which reads the denoised renders).

:class:`~arlight.methods.spec.MethodSpec` adds :data:`OPTIONS` to the options of every
method whose capabilities say ``noisy`` (``onepass``, ``reference``, ``dic``), as frame
options (denoising never changes what ``prepare`` builds). A deterministic method refuses
them with :data:`NOT_NOISY`.

Pure data (no NumPy, no Mitsuba): the method contract imports it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from arlight.scene.schema import Field

OPTIONS: dict[str, Field] = {
    "denoise": Field("choice", "none", "`oidn`: Intel Open Image Denoise on what the method "
                     "rendered (I_m, and I_r or the delta), composited onto the untouched "
                     "photograph (docs/methods/denoising.md); `none`: the raw Monte Carlo "
                     "estimate", choices=("none", "oidn")),
    "denoise_quality": Field("choice", "fast", "OIDN's quality level (`fast`: the best "
                             "equal-time PSNR on training worlds among settings whose added "
                             "bias stays small; rarely a small image's dark region comes out "
                             "too bright — docs/methods/denoising.md)",
                             choices=("fast", "balanced", "high")),
    "denoise_aux": Field("bool", True, "clean first-hit albedo and normal buffers (the first "
                         "non-specular hit behind mirrors and glass) guide the denoiser"),
    "denoise_target": Field("choice", "separate", "`separate`: I_m and I_r denoised with the "
                            "same auxiliary buffers and exposure, delta = D(I_m) − D(I_r); "
                            "`delta`: the signed delta denoised directly (its positive and "
                            "negative parts)", choices=("separate", "delta")),
    "denoise_device": Field("choice", "cpu", "where OIDN runs: `cpu`, or `cuda` (OIDN's "
                            "CUDA device on an NVIDIA GPU; refused with one line where there "
                            "is none; not run on this project's machines)",
                            choices=("cpu", "cuda")),
    "denoise_aux_spp": Field("int", 4, "sub-pixel samples of the auxiliary buffers (box "
                             "filter; at least 16 on a thin-lens camera)", min=1, max=256),
    "delta": Field("choice", "auto", "how a real pixel changes: `additive`: B + I_m − "
                   "I_r (Debevec; Kán Eq. 2.20); `ratio`: B + s (I_m − I_r) with s = B / I_r "
                   "(after the denoiser, if any), clipped so the implied albedo ρ s ≤ 1 — "
                   "photo-consistent where the proxy lost the photograph's texture "
                   "(arlight.layers.photo_scale, docs/methods/denoising.md); `auto`: ratio "
                   "with the denoiser on, additive without (chosen on training worlds: "
                   "+0.7 dB median with OIDN, a noisy undenoised I_r makes s noisy)",
                   choices=("auto", "additive", "ratio")),
}
"""``denoise``, ``denoise_quality``, ``denoise_aux``, ``denoise_target``,
``denoise_device``, ``denoise_aux_spp`` and the change's form ``delta`` (applied by
:meth:`arlight.methods.base.BaseMethod.render` after the denoiser)."""

NAMES = frozenset(OPTIONS)

NOT_NOISY = ("{method} is deterministic (no Monte Carlo noise): the denoiser applies only to "
             "the Monte Carlo methods (`arlight methods` lists a `denoise` option on them)")
"""The refusal of a denoise option on a method without Monte Carlo noise."""


@dataclass(frozen=True)
class DenoiseSettings:
    """The denoise options of one render.

    Attributes:
        quality: OIDN quality, ``fast`` | ``balanced`` | ``high``.
        aux: use clean albedo and normal buffers.
        target: ``separate`` (D(I_m) − D(I_r)) or ``delta`` (the delta itself).
        aux_spp: sub-pixel samples of the auxiliary buffers.
        device: OIDN's device, ``cpu`` | ``cuda``.
    """

    quality: str = "fast"
    aux: bool = True
    target: str = "separate"
    aux_spp: int = 4
    device: str = "cpu"

    @staticmethod
    def from_options(opts: Any) -> DenoiseSettings | None:
        """The settings from validated method options; None without ``denoise = oidn``
        (or on a method without the options)."""
        if opts.get("denoise", "none") == "none":
            return None
        return DenoiseSettings(quality=opts["denoise_quality"], aux=opts["denoise_aux"],
                               target=opts["denoise_target"], aux_spp=opts["denoise_aux_spp"],
                               device=opts.get("denoise_device", "cpu"))


def delta_form(opts: Any, denoised: bool) -> str:
    """The change's form a render applies: the ``delta`` option, ``auto`` resolved to
    ``ratio`` when the frame was denoised and ``additive`` when not (options without
    ``delta``, the real-time methods': ``additive``)."""
    form = opts.get("delta", "additive")
    if form == "auto":
        return "ratio" if denoised else "additive"
    return form


__all__ = ["DenoiseSettings", "NAMES", "NOT_NOISY", "OPTIONS", "delta_form"]
