"""The Method interface: prepare/render vs one-shot, posed views, options, stage timings,
discovery through entry points, shape checks at the public boundaries."""

from __future__ import annotations

import importlib.metadata
from dataclasses import replace

import numpy as np
import pytest

import arlight.methods as registry
from arlight.errors import InputError
from arlight.layer_files import write_layers
from arlight.methods import (
    BaseMethod,
    Capabilities,
    Field,
    Layers,
    MethodSpec,
    RenderSettings,
    available_methods,
    get_method,
    register,
    unregister,
)
from arlight.timing import StageTimer, stage_times
from tests.conftest import area_light_scene, env_mirror_scene, load, with_constant_frame

BUILTINS = ("reference", "onepass")
LAYERS = ("background", "mixed", "delta", "mask", "composite", "real")


def small(kind: str = "area"):
    d = area_light_scene(12, 9) if kind == "area" else env_mirror_scene(12, 9)
    return with_constant_frame(load(d))


def assert_same(a: Layers, b: Layers) -> None:
    for k in LAYERS:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert a.stderr.keys() == b.stderr.keys()
    for k in a.stderr:
        np.testing.assert_array_equal(a.stderr[k], b.stderr[k], err_msg=f"stderr {k}")


# ----------------------------------------------------------------- prepare / render
def test_state_of_another_method_or_other_options_is_refused():
    """Bug caught: a state rendered by the wrong method or with options it was not prepared
    with (silently rendering something else than asked)."""
    scene = small()
    ref, one = get_method("reference"), get_method("onepass")
    with pytest.raises(TypeError, match="onepass.prepare"):
        one.render(ref.prepare(scene.world), scene.view)
    state = one.prepare(scene.world, RenderSettings(options={"mode": "twopass"}))
    with pytest.raises(InputError, match="prepare again"):
        one.render(state, scene.view, RenderSettings())
    # a frame option (onepass: sample_offset) may differ; any other option still may not
    state = one.prepare(scene.world, RenderSettings(spp=2))
    frame = RenderSettings(spp=2, options={"sample_offset": 2})
    np.testing.assert_array_equal(one.render(state, scene.view, frame).composite,
                                  one(scene, frame).composite)
    with pytest.raises(InputError, match="prepare again"):
        one.render(state, scene.view, RenderSettings(spp=2, options={"sample_offset": 2,
                                                                     "mode": "twopass"}))


def test_frame_options_must_be_options():
    with pytest.raises(ValueError, match="frame option 'seed' is not an option"):
        MethodSpec(name="x", description="x", frame_options=frozenset({"seed"}))


# -------------------------------------------------------------------------- options
def test_option_types_defaults_and_command_line_strings():
    """Defaults fill missing options; ``"false"`` from the command line is False; a value of
    the wrong kind fails naming ``options.<key>``. Bugs caught: the string "false" read as
    truthy, defaults missing (KeyError in the method), wrong types passed through."""
    spec = get_method("onepass").spec
    assert dict(spec.defaults()) == {"env_mode": "mis", "mirror_lower_hemisphere": False,
                                     "reproject": True, "mode": "onepass",
                                     "caustics": "none", "photons": 200_000,
                                     "photon_radius": 0.01, "ppm_iterations": 1,
                                     "ppm_alpha": 0.7, "sampler": "sobol",
                                     "replicas": 16, "replica_mode": "blocks",
                                     "light_sampling": "importance", "sample_offset": 0,
                                     "denoise": "none", "denoise_quality": "fast",
                                     "denoise_aux": True, "denoise_aux_spp": 4,
                                     "denoise_target": "separate", "denoise_device": "cpu",
                                     "delta": "auto"}
    opts = spec.parse_options({"reproject": "false", "mode": "twopass"})
    assert opts.reproject is False and opts["mode"] == "twopass" and opts.env_mode == "mis"
    assert spec.parse_options({"reproject": "TRUE"}).reproject is True
    with pytest.raises(InputError, match=r"options\.reproject: expected true or false"):
        spec.parse_options({"reproject": 3})
    with pytest.raises(InputError, match=r"options\.env_mode: unknown value 'cdf'.*mis, "
                                         r"miss_only"):
        spec.parse_options({"env_mode": "cdf"})
    with pytest.raises(InputError, match=r"options\.mirror_lower_hemisphere.*miss_only"):
        spec.parse_options({"mirror_lower_hemisphere": "true"})
    num = MethodSpec("toy", "x", options={"n": Field("int", 2, min=1),
                                          "gain": Field("float", 1.0, unit="EV"),
                                          "tint": Field("rgb", 1.0, min=0.0)})
    assert dict(num.parse_options({"n": "4", "gain": "-0.5", "tint": "0.5,0.25,1"})) == {
        "n": 4, "gain": -0.5, "tint": [0.5, 0.25, 1.0]}
    with pytest.raises(InputError, match=r"options\.n: must be >= 1"):
        num.parse_options({"n": "0"})
    with pytest.raises(InputError, match=r"options\.n: expected a number"):
        num.parse_options({"n": "four"})


def test_the_tracer_sees_the_parsed_options():
    """Bug caught: options validated but not handed on (reproject=false still reprojects)."""
    from arlight.methods.onepass import tracer_options

    opts, mode = tracer_options(RenderSettings(max_depth=3, options={"reproject": "false"}))
    assert opts.reproject is False and opts.max_depth == 3 and mode == "onepass"


# -------------------------------------------------------------------- capabilities
def test_unsupported_material_fails_before_any_work():
    """Bug caught: a method run on a scene its capabilities exclude (wrong images, or a
    crash deep inside) instead of a clear error."""
    calls = []

    @register("test-diffuse-only", capabilities=Capabilities(materials={"diffuse"}))
    def diffuse_only(scene, settings):
        calls.append(1)
        raise AssertionError("must not run")

    try:
        with pytest.raises(InputError, match="does not support material type phong"):
            get_method("test-diffuse-only")(small("area"), RenderSettings())
        assert not calls
    finally:
        unregister("test-diffuse-only")


# -------------------------------------------------------------------------- timings
@pytest.mark.parametrize("name", BUILTINS)
def test_stage_timings_are_reported_and_add_up(name):
    """Bugs caught: a stage missing from the stats, nested or double-counted stages (their
    sum exceeding the wall time), ``seconds`` not covering the preparation."""
    layers = get_method(name)(small(), RenderSettings(spp=1))
    st = stage_times(layers.stats)
    assert {"prepare", "setup", "trace", "assemble"} <= set(st)
    assert all(v >= 0 for v in st.values())
    assert sum(st.values()) <= layers.stats["seconds"]


def test_a_stage_waits_for_dr_jit_before_stopping_the_clock(monkeypatch):
    """Dr.Jit runs kernels asynchronously; the stage must synchronise before reading the
    clock. Bug caught: a timer that stops at once, billing the kernel to a later stage."""
    import time

    import drjit as dr

    monkeypatch.setattr(dr, "sync_thread", lambda: time.sleep(0.05))
    timer = StageTimer()
    with timer.stage("trace"):
        pass
    assert timer.seconds["trace"] >= 0.05
    with pytest.raises(RuntimeError, match="do not nest"), timer.stage("a"), \
            timer.stage("b"):
        pass


# ----------------------------------------------------------------------- discovery
class ToyMethod(BaseMethod):
    """A method from "another package": the frame, unchanged."""

    spec = MethodSpec("toy-plugin", "Returns the frame unchanged (entry-point test).",
                      options={"gain": Field("float", 1.0, "unused", min=0.0)})

    def prepare_world(self, world, options, settings):
        return world

    def render_view(self, data, view, options, settings, timer):
        with timer.stage("render"):
            z = np.zeros_like(view.frame)
            return Layers.assemble(view.frame, z, z, np.zeros(view.frame.shape[:2]))


@pytest.fixture
def fake_entry_points(monkeypatch):
    """``importlib.metadata.entry_points`` returning a toy plug-in and a broken one."""
    eps = [importlib.metadata.EntryPoint("toy-plugin", f"{__name__}:ToyMethod",
                                         registry.ENTRY_POINT_GROUP),
           importlib.metadata.EntryPoint("broken-plugin", "no_such_module_xyz:Thing",
                                         registry.ENTRY_POINT_GROUP)]

    def entry_points(**kw):
        assert kw == {"group": registry.ENTRY_POINT_GROUP}
        return eps

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    with pytest.warns(RuntimeWarning, match="broken-plugin"):
        registry.refresh()
    yield
    unregister("toy-plugin")
    unregister("broken-plugin")


def test_entry_point_methods_are_discovered(fake_entry_points):
    """A method in another package registers through the ``arlight.methods`` entry-point
    group, with no list to edit; a broken plug-in is reported without hiding the others.
    Bugs caught: discovery reading only a hard-coded list, one failing entry point breaking
    every lookup."""
    assert "toy-plugin" in available_methods()
    assert set(BUILTINS) <= set(available_methods())  # fallback: still there
    assert "broken-plugin" in registry.load_errors()
    with pytest.raises(InputError, match="failed to load.*no_such_module_xyz"):
        get_method("broken-plugin")
    layers = get_method("toy-plugin")(small(), RenderSettings(options={"gain": "2"}))
    np.testing.assert_array_equal(layers.composite, small().frame)
    assert layers.method == "toy-plugin" and "time_render" in layers.stats


def test_builtins_load_without_package_metadata(monkeypatch):
    """Bug caught: a source checkout without installed metadata has no methods at all."""
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda **kw: [])
    saved = dict(registry._REGISTRY)
    try:
        registry._REGISTRY.clear()
        registry.refresh()
        assert set(BUILTINS) <= set(available_methods())
    finally:
        registry._REGISTRY.clear()
        registry._REGISTRY.update(saved)


# --------------------------------------------------------------------- shape checks
def test_assemble_names_the_bad_layer_and_the_expected_shape():
    """Bugs caught: a mask with a channel axis or the wrong size broadcast silently into
    the composite, integer code values taken for radiance, NaNs composited."""
    bg = np.zeros((4, 5, 3), np.float32)
    z = np.zeros_like(bg)
    with pytest.raises(ValueError, match=r"'mask' has shape \(4, 5, 1\); expected \(H, W\) "
                                         r"= \(4, 5\)"):
        Layers.assemble(bg, z, z, np.zeros((4, 5, 1)))
    with pytest.raises(ValueError, match=r"'delta' has shape \(5, 4, 3\); expected "
                                         r"\(H, W, 3\)"):
        Layers.assemble(bg, z, np.zeros((5, 4, 3)), np.zeros((4, 5)))
    with pytest.raises(ValueError, match=r"'mixed' has dtype uint8; expected float32"):
        Layers.assemble(bg, z.astype(np.uint8), z, np.zeros((4, 5)))
    bad = z.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"'real' has 1 non-finite values \(first at "
                                         r"\(1, 2, 0\)"):
        Layers.assemble(bg, z, z, np.zeros((4, 5)), real=bad)
    ok = Layers.assemble(bg, z.astype(np.float64), z, np.zeros((4, 5)))
    assert ok.mixed.dtype == np.float32  # float64 is converted, not refused


def test_write_layers_refuses_bad_layers_before_writing(tmp_path):
    """Bugs caught: EXRs of the wrong size or dtype written next to a good composite, a
    half-written output folder."""
    scene = small()
    layers = get_method("reference")(scene, RenderSettings(spp=1))
    wrong = replace(layers, delta=layers.delta.astype(np.float64))
    with pytest.raises(ValueError, match=r"write_layers: layer 'delta' has dtype float64"):
        write_layers(wrong, scene, tmp_path / "a")
    small_mask = replace(layers, mask=layers.mask[:-1])
    with pytest.raises(ValueError, match=r"'mask' has shape \(8, 12\); expected \(H, W\) = "
                                         r"\(9, 12\)"):
        write_layers(small_mask, scene, tmp_path / "b")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    write_layers(layers, scene, tmp_path / "c")  # stderr may be inf at 1 spp
    assert (tmp_path / "c" / "composite.png").is_file()


def test_register_rejects_non_methods():
    """Bug caught: an object without a spec registered, failing later in every lookup."""
    with pytest.raises(TypeError, match="not a Method"):
        register(object())
    with pytest.raises(ValueError, match="one line"):
        MethodSpec("x", "two\nlines")


def test_timer_stats_names():
    """``time_<stage>`` in seconds, summed when a stage repeats."""
    timer = StageTimer()
    timer.add("trace", 0.25)
    timer.add("trace", 0.5)
    assert timer.stats() == {"time_trace": 0.75} and timer.total == 0.75
