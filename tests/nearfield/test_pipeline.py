"""The server end to end: τ = 1 sends all light to the VALs (C_k = 0), τ = 0 none; a static
input gives identical VALs across updates (warm start); images by camera name."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.nearfield.cameras import auto_rig
from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings
from tests.nearfield.conftest import room, vbox, world


@pytest.fixture(scope="module")
def setup():
    w = world(room(virtual=[vbox()]))
    rig = auto_rig(np.array([-1, 0, -1.0]), np.array([1, 2, 1.0]), 32)[:5]
    rng = np.random.default_rng(0)
    imgs = [rng.uniform(0.1, 0.3, (32, 32, 3)).astype(np.float32) for _ in rig]
    for im in imgs:
        im[10:14, 10:14] = 30.0  # bright spots
    return w, rig, imgs


def test_tau_one_and_zero(setup):
    w, rig, imgs = setup
    s1 = NearFieldServer(w, rig, NearFieldSettings(atlas_resolution=48, tau=1.0, vals=4))
    light = s1.update(imgs)
    assert light.count == 4 and np.all(light.sh == 0)
    assert np.all(s1.last.indirect_atlas == 0)
    total = (s1.last.radiance * s1.area[:, None]).sum(0)
    assert np.allclose(light.intensity.sum(0), total, rtol=1e-9)
    s0 = NearFieldServer(w, rig, NearFieldSettings(atlas_resolution=48, tau=0.0, vals=4))
    light0 = s0.update(imgs)
    assert light0.count == 0 and np.all(light0.sh[0, 0] > 0)


def test_static_input_gives_identical_vals_and_names_work(setup):
    w, rig, imgs = setup
    s = NearFieldServer(w, rig, NearFieldSettings(atlas_resolution=48, tau=0.8, vals=6))
    s.update(imgs)
    a = s.update(imgs)
    b = s.update({c.name: im for c, im in zip(rig, imgs, strict=True)})
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.sh, b.sh)
    assert b.sequence == 3
    with pytest.raises(InputError, match="images"):
        s.update(imgs[:-1])


def test_settings_change_between_updates(setup):
    w, rig, imgs = setup
    s = NearFieldServer(w, rig, NearFieldSettings(atlas_resolution=48, tau=0.8, vals=6))
    assert s.update(imgs).count == 6
    new = NearFieldSettings(atlas_resolution=999, tau=0.8, vals=3)
    assert s.update(imgs, settings=new).count == 3
    assert new.atlas_resolution == 999 and s.settings.atlas_resolution == 48
    with pytest.raises(InputError, match="τ"):
        s.update(imgs, settings=NearFieldSettings(tau=1.5))
