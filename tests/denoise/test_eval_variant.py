"""``arlight eval`` method variants (``onepass+denoise=oidn``): the denoised method as its
own column of the same run (issue #31)."""

from __future__ import annotations

import pytest

from arlight.errors import InputError
from arlight.evaluate.harness import EvalConfig, method_options, run_evaluation
from arlight.evaluate.variants import split_variant

pytest.importorskip("pyoidn")


def test_variant_names_carry_their_options():
    """Rejects: a variant's options lost (it would run as the plain method), applied to the
    plain method too, or not validated (a typo renders with defaults)."""
    assert split_variant("onepass") == ("onepass", {})
    assert split_variant("onepass+denoise=oidn+denoise_quality=fast") == (
        "onepass", {"denoise": "oidn", "denoise_quality": "fast"})
    out = method_options(["onepass", "onepass+denoise=oidn"], {"denoise_quality": "fast"})
    assert out == {"onepass": {"denoise_quality": "fast"},
                   "onepass+denoise=oidn": {"denoise": "oidn", "denoise_quality": "fast"}}
    with pytest.raises(InputError, match="options.denoise"):
        method_options(["onepass+denoise=maybe"], {})
    with pytest.raises(InputError, match="deterministic"):
        method_options(["dlpv+denoise=oidn"], {})
    with pytest.raises(InputError, match="METHOD\\+key=value"):
        split_variant("onepass+denoise")


def test_eval_runs_the_plain_method_and_its_denoised_variant(eval_cache):
    """Both columns in one run, the variant denoised (its stats have the denoiser's stage)
    and closer to the ground truth at 4 spp. Rejects: a variant name that fails to resolve
    to its method, options not reaching the render."""
    cfg = EvalConfig(methods=["onepass", "onepass+denoise=oidn"], scenes=["bunny-box"],
                     spp=4, gt_spp=16, repeats=1, cache_dir=eval_cache)
    cells = {c.method: c for c in run_evaluation(cfg).cells}
    plain, dn = cells["onepass"], cells["onepass+denoise=oidn"]
    assert plain.ok and dn.ok, (plain.error, dn.error)
    assert "time_denoise" in dn.stats and "time_denoise" not in plain.stats
    assert dn.metrics["rmse"] < plain.metrics["rmse"]
