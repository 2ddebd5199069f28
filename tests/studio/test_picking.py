"""Ray queries against the demo proxy: picking the posed bunny, standing it on the table."""

from __future__ import annotations

import numpy as np


def _on_worker(engine, fn, *args):
    return engine.call(fn, *args).result(60)


def test_pick_finds_the_posed_object_and_not_its_old_place(studio_server, studio_engine):
    proxy = studio_engine.proxy
    rest = dict(studio_engine.rest_poses)
    head = proxy.project(rest["bunny"].position + [0.0, 0.05, 0.0])
    assert _on_worker(studio_engine, proxy.pick, *head, rest) == "bunny"
    assert _on_worker(studio_engine, proxy.pick, 5.0, 115.0, rest) is None  # the table
    # moved 0.25 m to the left: found at its new place only (picking uses the pose)
    moved = {"bunny": rest["bunny"].moved_to(rest["bunny"].position + [-0.25, 0.0, 0.0])}
    new_head = proxy.project(moved["bunny"].position + [0.0, 0.05, 0.0])
    assert _on_worker(studio_engine, proxy.pick, *new_head, moved) == "bunny"
    assert _on_worker(studio_engine, proxy.pick, *head, moved) is None


def test_support_is_the_table_top_and_placement_lands_under_the_pointer(studio_server,
                                                                        studio_engine):
    proxy = studio_engine.proxy
    hit = _on_worker(studio_engine, proxy.support, 40.0, 90.0)
    assert hit.shape == "table"
    np.testing.assert_allclose(hit.normal, [0, 1, 0], atol=1e-6)
    assert abs(hit.position[1]) < 1e-6
    # the anchor moved there projects back onto the same pixel
    pose = studio_engine.rest_poses["bunny"].moved_to(hit.position)
    np.testing.assert_allclose(proxy.project(pose.position), (40.0, 90.0), atol=1e-3)
    # the sky (a miss) and the red box's front face (vertical) are no support; its lid is
    assert _on_worker(studio_engine, proxy.support, 80.0, 1.0) is None
    box = next(s for s in studio_engine.scene.shapes if s.name == "red_box")
    front = proxy.project((box.to_world @ [0.0, -0.03, 0.089, 1.0])[:3])
    assert _on_worker(studio_engine, proxy.support, *front) is None
    lid = _on_worker(studio_engine, proxy.support,
                     *proxy.project((box.to_world @ [0.0, 0.09, 0.0, 1.0])[:3]))
    assert lid.shape == "red_box" and abs(lid.position[1] - 0.18) < 1e-4
