"""Denoised differential rendering (issue #31): the photograph is never denoised, a
converged render survives the denoiser, the bias is bounded, the raw layers stay, the option
is refused where it makes no sense."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.denoise.bias import region_bias, regions
from arlight.denoise.differential import footprint, footprint_radius, undenoised
from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from tests.conftest import area_light_scene, env_mirror_scene, load

pytest.importorskip("pyoidn")

W, H = 96, 72


def textured(scene, seed: int = 3):
    """``scene`` with a high-frequency random photograph (a denoiser would smooth it)."""
    rng = np.random.default_rng(seed)
    h, w = scene.camera.height, scene.camera.width
    img = rng.uniform(0.05, 0.9, (h, w, 3)).astype(np.float32)
    return scene.with_frame(img)


@pytest.fixture(scope="module")
def converged():
    """The textured area-light scene and a converged ``reference`` of it (512 spp;
    Mitsuba's path tracer, code independent of onepass)."""
    scene = textured(load(area_light_scene(W, H)))
    return scene, render(scene, method="reference", spp=512, seed=11)


def render(scene, method="onepass", spp=1, seed=0, **options):
    """``method``'s layers; the change additive unless asked (these tests are about the
    denoiser, and their random photographs are no image of the proxy, which ``delta =
    ratio``, the default with the denoiser on, would read them as)."""
    m = get_method(method)
    return m(scene, RenderSettings(spp=spp, seed=seed,
                                   options={"delta": "additive", **options}))


@pytest.mark.parametrize("target", ["separate", "delta"])
def test_photo_is_preserved_bit_for_bit_outside_the_footprint(target):
    """Outside the insertion's footprint the denoised composite is the photograph, bit for
    bit, on a textured photo. Rejects: denoising the composite or the relit photo (the
    texture would be smoothed everywhere), ``D(I_m) − D(I_r)`` left unclipped (OIDN's
    nonlocal filter leaks a small delta into every pixel), a delta added after a float64
    round trip."""
    scene = textured(load(area_light_scene(W, H)))
    out = render(scene, denoise="oidn", denoise_target=target)
    raw = undenoised(out)
    fp = footprint(raw.delta, raw.mask, footprint_radius(W))
    assert 0.05 < fp.mean() < 0.9, "the test needs pixels on both sides of the footprint"
    assert np.array_equal(out.composite[~fp], scene.view.frame[~fp])
    assert not np.any(out.delta[~fp]) and not np.any(out.mask[~fp])
    # inside, the denoiser did change something (the test is not vacuous)
    assert not np.array_equal(out.composite[fp], raw.composite[fp])


def test_without_virtual_objects_the_composite_is_the_photo():
    """No virtual object: delta 0 and mask 0 everywhere, the denoised composite is the
    photograph bit for bit. Rejects: a denoiser run on I_m alone or on the composite."""
    scene = textured(load(area_light_scene(W, H, virtual=False)))
    out = render(scene, denoise="oidn")
    assert np.array_equal(out.composite, scene.view.frame)


def test_denoised_converged_render_equals_it_within_noise():
    """A converged render (256 spp) denoised equals itself within its own noise: ≥ 97 % of
    the composite's pixels within 4 standard errors (+1e-4), and the mean signed difference
    over the footprint below 0.5 % of its mean. Rejects: a delta of the wrong sign
    (``D(I_r) − D(I_m)``), I_m and I_r denoised at different exposures (an offset in every
    shadow), the composite assembled on the denoised rather than the raw mask."""
    scene = textured(load(area_light_scene(48, 36)))
    out = render(scene, spp=256, denoise="oidn")
    raw = undenoised(out)
    se = raw.stderr["composite"]
    diff = out.composite - raw.composite
    assert np.mean(np.abs(diff) <= 4 * se + 1e-4) >= 0.97
    fp = footprint(raw.delta, raw.mask, footprint_radius(48))
    rel = diff[fp].mean() / raw.composite[fp].mean()
    assert abs(rel) < 0.005, rel


def test_raw_layers_and_their_standard_errors_are_kept():
    """``noisy`` is the render without the denoiser, bit for bit, with its standard errors;
    the unbiasedness tests run on it. Rejects: a denoiser that writes into the raw arrays,
    raw layers lost, standard errors of the raw estimate presented as the denoised one's."""
    scene = textured(load(area_light_scene(W, H)))
    plain = render(scene, spp=4, seed=7)
    out = render(scene, spp=4, seed=7, denoise="oidn")
    raw = undenoised(out)
    for k in ("mixed", "delta", "composite", "real"):
        assert np.array_equal(getattr(raw, k), getattr(plain, k)), k
    assert set(raw.stderr) == set(plain.stderr)
    assert out.stderr == {}
    assert out.stats["time_denoise"] > 0 and out.stats["denoise_runs"] == 2


def test_denoising_lowers_the_error_against_a_converged_reference(converged):
    """onepass at 4 spp denoised is closer to a converged ``reference`` (Mitsuba's path
    tracer: other code) than undenoised, with and without auxiliary buffers. Rejects: a
    denoiser that returns its input, aux buffers that mislead it (e.g. camera-space
    normals of the wrong sign would still pass, but a zero albedo fails)."""
    scene, ref = converged
    truth = ref.composite
    raw = render(scene, spp=4).composite
    rmse = {k: float(np.sqrt(np.mean((render(scene, spp=4, denoise="oidn", denoise_aux=a)
                                      .composite - truth) ** 2)))
            for k, a in (("aux", True), ("no_aux", False))}
    r_raw = float(np.sqrt(np.mean((raw - truth) ** 2)))
    assert rmse["aux"] < 0.6 * r_raw and rmse["no_aux"] < 0.6 * r_raw, (rmse, r_raw)


def test_bias_is_bounded_and_reported_by_region(converged):
    """The relative mean signed error of denoised onepass (4 spp) against a converged
    ``reference`` is below 5 % in the shadow, on the object and at the silhouette, and the
    bias function finds a known offset exactly. Rejects: a denoiser that fills shadows
    (e.g. the delta clipped to the raw support only at 1 spp), bias regions computed from
    the result (they would follow its errors)."""
    scene, ref = converged
    out = render(scene, spp=4, denoise="oidn")
    b = region_bias(out.composite, ref.composite, scene.view.frame, ref.mask)
    for k in ("shadow", "object", "silhouette"):
        assert b[f"pixels_{k}"] > 10, b
        assert abs(b[k]) < 0.05, b
    reg = regions(ref.composite, scene.view.frame, ref.mask)
    shifted = ref.composite.copy()
    shifted[reg["shadow"]] *= 1.1
    known = region_bias(shifted, ref.composite, scene.view.frame, ref.mask)
    assert known["shadow"] == pytest.approx(0.1, rel=1e-5)
    assert known["object"] == 0.0


@pytest.mark.parametrize("method", ["dlpv", "dir", "dvct", "ibl", "prt"])
def test_option_is_refused_on_deterministic_methods(method):
    """Rejects: a deterministic method silently ignoring ``denoise``, or refusing it with
    the generic unknown-option message that does not say why."""
    with pytest.raises(InputError) as err:
        get_method(method).spec.parse_options({"denoise": "oidn"})
    assert err.value.field == "options.denoise"
    assert "deterministic" in str(err.value)


def test_option_is_refused_on_the_command_line_with_one_line_and_exit_2(tmp_path, capsys):
    """``arlight render -m dlpv --option denoise=oidn``: exit 2, one line, no output, no
    traceback."""
    import json

    from arlight.cli import main

    d = area_light_scene(16, 12)
    import imageio.v3 as iio

    iio.imwrite(tmp_path / "frame.png", np.full((12, 16, 3), 128, np.uint8))
    d["frame"] = {"image": "frame.png"}
    (tmp_path / "s.json").write_text(json.dumps(d))
    out = tmp_path / "out"
    code = main(["render", str(tmp_path / "s.json"), "-m", "dlpv", "--option",
                 "denoise=oidn", "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists()
    assert len(err.splitlines()) == 1 and "deterministic" in err and "Traceback" not in err


def test_cuda_device_is_refused_cleanly_where_there_is_none(tmp_path, capsys):
    """``--option denoise_device=cuda`` on a machine without a CUDA device: exit 2, one line
    naming the option, no output, no traceback. Rejects falling back to the CPU silently
    and a raw OIDN/ctypes error. (The CUDA path itself cannot run here.)"""
    import json

    import imageio.v3 as iio
    import pyoidn

    from arlight.cli import main

    if pyoidn.Device.is_cuda_available():
        pytest.skip("this machine has a CUDA device")
    d = area_light_scene(16, 12)
    iio.imwrite(tmp_path / "frame.png", np.full((12, 16, 3), 128, np.uint8))
    d["frame"] = {"image": "frame.png"}
    (tmp_path / "s.json").write_text(json.dumps(d))
    out = tmp_path / "out"
    code = main(["render", str(tmp_path / "s.json"), "-m", "onepass", "--spp", "1",
                 "--option", "denoise=oidn", "--option", "denoise_device=cuda",
                 "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists()
    assert len(err.splitlines()) == 1 and "denoise_device" in err and "CUDA" in err
    assert "Traceback" not in err


def test_monte_carlo_methods_list_the_options():
    """Rejects: a Monte Carlo method without the denoiser's options, or a denoise option
    that forces a new preparation (it only changes the frame)."""
    for name in ("onepass", "reference", "dic"):
        spec = get_method(name).spec
        assert {"denoise", "denoise_quality", "denoise_aux", "denoise_target"} <= set(
            spec.options), name
        assert "denoise" in spec.frame_options
        assert spec.capabilities.noisy
    assert not get_method("dlpv").spec.capabilities.noisy
    assert get_method("onepass").spec.parse_options({"denoise_aux": "off"}).denoise_aux is False


def test_aux_buffers_take_the_first_non_specular_hit():
    """Behind a real mirror (reflectance 0.9) the albedo buffer holds the mirror's
    reflectance times the floor's albedo (0.5) and the floor's world-space normal; a plain
    floor pixel holds 0.5 and (0, 1, 0); the environment 0. Rejects: the mirror's own
    (zero) diffuse albedo, camera-space normals, albedo not multiplied by the specular
    weight."""
    from arlight.denoise.aux import aux_buffers
    from arlight.tracing.scenes import prepare_scenes

    scene = load(env_mirror_scene(64, 48))
    views = prepare_scenes(scene.world).views
    aux = aux_buffers(views.mixed, scene.camera, samples=4)
    real = aux_buffers(views.real, scene.camera, samples=4)
    # pixels whose every sample ends on the floor (normal exactly up), straight or through
    # the mirror: albedo 0.5 or 0.9 · 0.5 (mixtures at the mirror's edge), nothing else
    up = np.all(np.abs(real.normal - [0, 1, 0]) < 1e-5, axis=-1)
    grey = np.round(real.albedo[up], 4)
    assert np.all(grey == grey[:, :1])
    direct, mirrored = (grey[:, 0] == 0.5).sum(), (grey[:, 0] == 0.45).sum()
    assert direct > 50 and mirrored > 20, (direct, mirrored)
    assert np.all((grey >= 0.45) & (grey <= 0.5))
    assert np.all(np.abs(real.albedo) <= 1.0) and np.all(np.abs(real.normal) <= 1.0 + 1e-6)
    # the virtual sphere's albedo appears in the mixed view only
    blue = np.isclose(aux.albedo[..., 2], 0.8, atol=1e-3)
    assert blue.sum() > 10 and not np.isclose(real.albedo[..., 2], 0.8, atol=1e-3).any()


def test_progressive_refinement_denoises_the_mean_of_raw_frames():
    """After 3 refinement frames the image is the denoised composite of the mean of the 3
    raw frames (averaged here, independently of the refinement loop). Rejects: a mean of
    denoised frames (the denoiser's bias would never fall), frames rendered denoised."""
    from arlight.denoise.aux import aux_buffers
    from arlight.denoise.differential import denoise_layers
    from arlight.denoise.options import DenoiseSettings
    from arlight.layers import Layers
    from arlight.progressive import frame_settings, refine

    scene = textured(load(area_light_scene(W, H)))
    s = RenderSettings(spp=2, seed=5, options={"denoise": "oidn"})
    steps = list(refine(scene, "onepass", s, frames=3))
    m = get_method("onepass")
    plain = RenderSettings(spp=2, seed=5)
    raws = [m(scene, frame_settings(m, plain, n)) for n in (1, 2, 3)]
    mean = {k: np.mean([getattr(r, k).astype(np.float64) for r in raws], axis=0)
            .astype(np.float32) for k in ("mixed", "real", "delta", "mask")}
    layers = Layers.assemble(scene.view.frame, mean["mixed"], mean["delta"], mean["mask"],
                             real=mean["real"])
    state = m.prepare(scene.world, plain)
    full = aux_buffers(state.data.views.mixed, scene.camera, 4)
    want = denoise_layers(layers, DenoiseSettings(),
                          lambda r, c: full.crop(r, c)).composite
    assert np.allclose(steps[-1].image, want, atol=1e-6)
    assert not any(getattr(st.layers, "noisy", None) for st in steps)  # frames are raw


def test_render_writes_the_raw_layers_next_to_the_denoised_ones(tmp_path):
    """``arlight render --option denoise=oidn`` writes the denoised layers and the raw
    estimate (``noisy_*.exr``) with its standard errors. Rejects: the raw layers or their
    errors missing from the output."""
    import json

    import imageio.v3 as iio

    from arlight.cli import main
    from arlight.io.images import read_hdr

    d = area_light_scene(32, 24)
    iio.imwrite(tmp_path / "frame.png", np.full((24, 32, 3), 100, np.uint8))
    d["frame"] = {"image": "frame.png"}
    (tmp_path / "s.json").write_text(json.dumps(d))
    out = tmp_path / "out"
    assert main(["render", str(tmp_path / "s.json"), "-m", "onepass", "--spp", "4",
                 "--option", "denoise=oidn", "-o", str(out)]) == 0
    for name in ("composite", "noisy_composite", "noisy_delta", "noisy_mixed",
                 "stderr_composite"):
        assert (out / f"{name}.exr").is_file(), name
    assert not np.array_equal(read_hdr(out / "composite.exr"),
                              read_hdr(out / "noisy_composite.exr"))
    assert json.loads((out / "stats.json").read_text())["denoise_runs"] >= 1
