"""Generated worlds (issue #30): deterministic per seed, the whole distribution drawn, valid
scene files, proxies coarser than their worlds, the training/held-out split."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.evaluate import worlds as W
from arlight.scene.load import load_scene

SEEDS = W.split_seeds("training", 100) + W.split_seeds("heldout", 100)


@pytest.fixture(scope="module")
def drawn() -> list[W.GeneratedWorld]:
    return [W.generate(s) for s in SEEDS]


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_same_files_bitwise(tmp_path):
    """Rejects a generator that draws from a global or time-seeded RNG, or iterates a set."""
    for seed in (3, W.HELDOUT_BASE + 5):
        a, b = tmp_path / f"a{seed}", tmp_path / f"b{seed}"
        W.generate(seed).write(a)
        W.generate(seed).write(b)
        fa, fb = _files(a), _files(b)
        assert fa == fb and "world.toml" in fa and "proxy.toml" in fa
    assert _files(tmp_path / "a3")["world.toml"] != _files(
        tmp_path / f"a{W.HELDOUT_BASE + 5}")["world.toml"]


def test_two_hundred_seeds_cover_the_distribution(drawn):
    """Every item of the issue's distribution appears among 200 seeds (rejects a generator
    stuck on a subset, e.g. one that never places a light behind the camera)."""
    classes = Counter(w.world_class for w in drawn)
    assert set(classes) == set(W.CLASSES) and min(classes.values()) >= 30
    scales = [w.tags["scale"] for w in drawn]
    assert min(scales) <= 0.4 and max(scales) >= 40.0
    rooms = [w for w in drawn if w.world_class == "room"]
    assert all({"ceiling", "floor"} <= {s["name"] for s in w.world["shapes"]} for w in rooms)
    assert sum(w.tags["room_open"] == "none" for w in rooms) >= 5

    env = Counter(w.tags["env"] for w in drawn)
    assert env["hdr"] >= 60 and env["constant"] >= 20 and env["none"] >= 3
    assert {w.tags["hdr"] for w in drawn if w.tags["hdr"]} == {
        p.split("/")[-1] for p in W.HDR_MAPS}
    rotations = [x["rotation_deg"] for w in drawn for x in w.world["lights"]
                 if x["type"] == "envmap"]
    scales_env = [x["scale"] for w in drawn for x in w.world["lights"] if x["type"] == "envmap"]
    assert max(rotations) - min(rotations) > 300 and max(scales_env) / min(scales_env) > 8

    lights = [x for w in drawn for x in w.tags["lights"]]
    assert Counter(len(w.tags["lights"]) for w in drawn).keys() == {0, 1, 2, 3}
    assert {x["type"] for x in lights} == set(W.LIGHT_TYPES)
    assert sum(w.tags["sun"] for w in drawn) >= 10
    assert {x["placement"] for x in lights} == set(W.PLACEMENTS)
    sizes = [x["size"] for x in lights if x["type"] in ("area", "sphere")]
    assert min(sizes) <= 0.015 and max(sizes) >= 1.5
    radiance = [x["radiance"] for x in lights if x["radiance"] > 0]
    assert max(radiance) / min(radiance) >= 1000

    assert set(W.REAL_MATERIALS) <= set().union(*(w.tags["real_materials"] for w in drawn))
    assert set(W.VIRTUAL_MATERIALS) <= set().union(
        *(w.tags["virtual_materials"] for w in drawn))
    assert sum(w.tags["textured"] for w in drawn) >= 40
    assert sum(w.tags["all_diffuse"] for w in drawn) >= 20
    meshes = Counter(m for w in drawn for m in w.tags["meshes"])
    assert set(meshes) == {*W.MESHES, "sphere", "box"}
    contact = Counter(c for w in drawn for c in w.tags["contact"])
    assert contact["touching"] >= 50 and contact["floating"] >= 30
    assert 30 <= sum(w.tags["dof"] for w in drawn) <= 170


def test_light_reaches_the_objects_in_every_world(drawn):
    """A world without an environment, or a room closed on all sides, has a local light
    (rejects generator v1, which drew closed rooms lit only by a sky outside their walls:
    black frames on which every method "agrees" at 60 dB)."""
    for w in drawn:
        closed = w.world_class == "room" and w.tags["room_open"] == "none"
        if w.tags["env"] == "none" or closed:
            assert w.tags["lights"], w.seed
    assert W.generate(1000023).tags["lights"]


def test_the_proxy_is_coarser_than_the_world(drawn):
    """Each kind of imperfection occurs, and only as described: the proxy's camera and lights
    are the world's, and it has no shape the world lacks."""
    kinds = Counter(e.split(": ")[1].split(" ")[0] for w in drawn for e in w.tags["proxy_edits"])
    assert {"texture", "bevels", "offset", "missing"} <= set(kinds)
    assert sum(bool(w.tags["proxy_edits"]) for w in drawn) >= 0.8 * len(drawn)
    for w in drawn:
        assert w.proxy["camera"] == w.world["camera"] and w.proxy["lights"] == w.world["lights"]
        assert {s["name"] for s in w.proxy["shapes"]} <= {s["name"] for s in w.world["shapes"]}
        virtual = [s for s in w.world["shapes"] if s["role"] == "virtual"]
        assert virtual == [s for s in w.proxy["shapes"] if s["role"] == "virtual"]


def test_written_worlds_load_as_valid_scenes(tmp_path, drawn):
    """What ``arlight validate`` checks: each written file loads (rejects a generator that
    writes a field the scene format refuses, or a path that does not travel with the
    folder)."""
    for w in drawn[::10]:
        paths = w.write(tmp_path / w.name, width=80)
        world, proxy = load_scene(paths["world"]), load_scene(paths["proxy"])
        assert world.resolution == proxy.resolution == (80, 60)
        assert world.virtual_shapes and world.lights
        text = paths["world"].read_text()
        assert all(f'"assets/{p.name}"' in text for p in w.assets())  # travels with it


def test_exposure_shows_grey_at_the_target():
    """``auto_exposure`` maps a 50 % grey Lambertian surface under E to 0.18: radiance
    0.5·E/π times 2^exposure (independent arithmetic)."""
    for e in (0.01, 1.0, 3000.0):
        assert 0.5 * e / math.pi * 2 ** W.auto_exposure(e) == pytest.approx(0.18, rel=0.01)


def test_light_placement_relative_to_the_camera():
    cam, target = np.array([0.0, 1.0, 5.0]), np.zeros(3)
    assert W.light_placement([0, 3, 8], cam, target) == "behind"
    assert W.light_placement([0, 3, -4], cam, target) == "front"
    assert W.light_placement([4, 3, 0.5], cam, target) == "beside"


def test_splits_and_world_lists():
    assert W.split_seeds("training", 3) == [0, 1, 2]
    assert W.split_seeds("heldout", 2, 5) == [W.HELDOUT_BASE + 5, W.HELDOUT_BASE + 6]
    assert W.parse_worlds("heldout:2+5") == W.split_seeds("heldout", 2, 5)
    assert W.parse_worlds("3, 1000004") == [3, 1000004]
    assert [W.split_of(s) for s in (0, W.HELDOUT_BASE - 1, W.HELDOUT_BASE)] == [
        "training", "training", "heldout"]
    for bad in ("heldout", "heldout:x", "nowhere:3", "heldout:0", "training:1+999999", "",
                "-4", f"heldout:{W.MAX_WORLDS + 1}"):
        with pytest.raises(InputError) as e:
            W.parse_worlds(bad)
        assert e.value.field == "worlds" or e.value.field == "seed"


def test_worlds_make_writes_a_method_ready_world(tmp_path):
    """``arlight worlds make``: the proxy names its frame and depth and loads with them; the
    depth is the first *real* surface (NaN only where the ray leaves the world); a second run
    into the same folder replaces only what it wrote; a foreign folder is refused."""
    from arlight import cli
    from tests.cli_invoke import MainRunner

    run = MainRunner()
    out = tmp_path / "w"
    seed = W.split_seeds("heldout", 1)[0]
    r = run.invoke(cli.app, ["worlds", "make", "--seed", seed, "-o", out, "--width", 16,
                             "--spp", 4, "--no-cache"])
    assert r.exit_code == 0, r.output
    proxy = load_scene(out / "proxy.toml")
    assert proxy.frame is not None and proxy.frame.shape == (12, 16, 3)
    assert proxy.depth is not None and np.nanmin(proxy.depth) > 0
    r = run.invoke(cli.app, ["worlds", "make", "--seed", seed, "-o", out, "--width", 16,
                             "--no-render"])
    assert r.exit_code == 0, r.output
    assert not (out / "frame.exr").exists() and load_scene(out / "proxy.toml").frame is None
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    r = run.invoke(cli.app, ["worlds", "make", "--seed", 1, "-o", foreign, "--no-render"])
    assert r.exit_code == 2 and "notes.txt" in r.stderr
    assert (foreign / "notes.txt").read_text() == "keep" and len(list(foreign.iterdir())) == 1
    r = run.invoke(cli.app, ["worlds", "list", "--worlds", "heldout:x"])
    assert r.exit_code == 2 and "worlds" in r.stderr


@pytest.mark.parametrize("args, needle", [
    (["worlds", "make", "--seed", "-1", "-o", "{tmp}/o"], "seed"),
    (["worlds", "make", "-o", "{tmp}/o"], "seed"),
    (["worlds", "make", "--seed", "1", "-o", "{tmp}/o", "--spp", "1"], "spp"),
    (["worlds", "make", "--seed", "1", "-o", "{tmp}/o", "--width", "4"], "width"),
    (["worlds", "make", "--seed", "1", "-o", "{tmp}/afile"], "afile"),
    (["worlds", "list", "--worlds", "elsewhere:3"], "worlds"),
    (["eval", "--worlds", "heldout:x", "-o", "{tmp}/e"], "worlds"),
    (["eval", "--worlds", "heldout:1", "--ladder", "0", "-o", "{tmp}/e"], "ladder"),
    (["eval", "--worlds", "heldout:1", "--ladder", "", "-o", "{tmp}/e"], "ladder"),
    (["eval", "--worlds", "heldout:1", "--width", "2", "-o", "{tmp}/e"], "width"),
])
def test_bad_world_input_is_one_line_exit_2_and_writes_nothing(tmp_path, args, needle):
    """The bad-input contract (docs/cli.md) for ``worlds`` and ``eval --worlds``: exit 2,
    one ``error:`` line naming the option, no output folder created, a file left as it
    was."""
    from arlight import cli
    from tests.cli_invoke import MainRunner

    (tmp_path / "afile").write_text("mine")
    r = MainRunner().invoke(cli.app, [a.format(tmp=tmp_path) for a in args])
    assert r.exit_code == 2, r.output
    assert needle in r.stderr and r.stderr.count("rror") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    assert (tmp_path / "afile").read_text() == "mine"
