"""The studio page in a real headless Chromium (Playwright, Debian's chromium package):
it loads and shows a composite, a drag moves the object and its shadow, the method
switches, the save button writes a scene file. Skipped when no browser is installed."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.studio.browser import launch, why_no_browser
from tests.studio.conftest import SIZE

pytestmark = pytest.mark.skipif(why_no_browser() is not None,
                                reason=f"studio browser tests: {why_no_browser()}")

TIMEOUT_MS = 120_000


@pytest.fixture(scope="module")
def page(studio_server):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = launch(p)
        pg = browser.new_page(viewport={"width": 1100, "height": 640})
        errors: list[str] = []
        pg.on("pageerror", lambda exc: errors.append(str(exc)))
        pg.goto(studio_server.url)
        pg.wait_for_function("window.studio.frames >= 1", timeout=TIMEOUT_MS)
        pg.errors = errors
        yield pg
        browser.close()


def _session(engine):
    return max(engine.sessions, key=lambda s: s.id)


def _snapshot(engine):
    """The page's session layers, read on the render worker between two jobs."""
    s = _session(engine)
    return engine.call(lambda: {k: np.array(v) for k, v in s.images.items()}).result(60)


def _canvas(page) -> np.ndarray:
    data = page.evaluate("""() => {
        const c = document.getElementById('frame');
        return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data);
    }""")
    return np.array(data, np.float64).reshape(SIZE[1], SIZE[0], 4)[..., :3]


def _client_xy(page, x: float, y: float) -> tuple[float, float]:
    """Page coordinates of studio pixel (x, y)."""
    box = page.locator("#frame").bounding_box()
    return box["x"] + x / SIZE[0] * box["width"], box["y"] + y / SIZE[1] * box["height"]


def _centroid(weights: np.ndarray) -> np.ndarray:
    ys, xs = np.indices(weights.shape)
    w = weights.sum()
    assert w > 0
    return np.array([(xs * weights).sum() / w, (ys * weights).sum() / w])


def _shadow(images) -> np.ndarray:
    """Darkening of the real surfaces by the object: −Δ luminance outside the object."""
    lum = images["delta"].mean(axis=2)
    return np.clip(-lum, 0, None) * (images["mask"] < 0.01)


def test_page_loads_and_shows_the_first_composite(page, studio_engine):
    assert page.title() == "arlight studio"
    assert page.evaluate("window.studio.header.method") == "dir"
    img = _canvas(page)
    assert img.std() > 10  # a picture, not a blank canvas
    assert page.locator("#method option").count() == len(studio_engine.catalogue)
    assert not page.errors


def test_drag_moves_the_object_and_its_shadow(page, studio_engine):
    proxy = studio_engine.proxy
    rest = studio_engine.rest_poses["bunny"]
    before_img = _canvas(page)
    before = _snapshot(studio_engine)
    start = proxy.project(rest.position + [0.0, 0.04, 0.0])
    target = (start[0] - 45.0, start[1] + 12.0)
    page.mouse.move(*_client_xy(page, *start))
    page.mouse.down()
    for t in np.linspace(0, 1, 8)[1:]:
        page.mouse.move(*_client_xy(page, start[0] + t * (target[0] - start[0]),
                                    start[1] + t * (target[1] - start[1])))
    page.mouse.up()
    last = page.evaluate("window.studio.seq")
    page.wait_for_function(f"window.studio.header.seq >= {last} && "
                           "!window.studio.header.superseded", timeout=TIMEOUT_MS)
    after_img = _canvas(page)
    after = _snapshot(studio_engine)
    move = np.subtract(target, start)
    # the object went where the pointer went (perspective changes its size a little)
    shift = _centroid(after["mask"]) - _centroid(before["mask"])
    assert np.linalg.norm(shift - move) < 0.25 * np.linalg.norm(move), (shift, move)
    # its shadow on the table followed it
    shadow_shift = _centroid(_shadow(after)) - _centroid(_shadow(before))
    assert shadow_shift @ move > 0.5 * (move @ move), (shadow_shift, move)
    # the page shows it: the composite changed where the object was and now is, and a
    # corner far from both did not change
    old = np.array(start, int)
    new = np.array(target, int)
    assert np.abs(after_img - before_img)[old[1] - 4:old[1] + 4, old[0] - 4:old[0] + 4].mean() > 8
    assert np.abs(after_img - before_img)[new[1] - 4:new[1] + 4, new[0] - 4:new[0] + 4].mean() > 8
    assert np.abs(after_img - before_img)[:12, -20:].max() <= 3
    assert not page.errors


def test_method_switch_to_progressive_onepass_refines(page):
    page.select_option("#method", "onepass")
    page.wait_for_function("window.studio.header.method === 'onepass' && "
                           "window.studio.header.refine >= 3", timeout=TIMEOUT_MS)
    assert "refining" in page.inner_text("#refine")
    page.select_option("#method", "dir")
    page.wait_for_function("window.studio.header.method === 'dir'", timeout=TIMEOUT_MS)
    assert not page.errors


def test_save_button_writes_a_valid_scene_file(page, studio_engine):
    from arlight.scene.load import load_scene

    page.fill("#save-name", "from_browser")
    page.click("#save")
    page.wait_for_function("document.getElementById('saved').textContent.length > 0",
                           timeout=TIMEOUT_MS)
    assert "from_browser.toml" in page.inner_text("#saved")
    sc = load_scene(studio_engine.save_dir / "from_browser.toml")
    pos = page.evaluate("window.studio.header.objects.bunny.position")
    bunny = next(s for s in sc.shapes if s.name == "bunny")
    rest = next(s for s in studio_engine.full.shapes if s.name == "bunny")
    pose = studio_engine.rest_poses["bunny"].moved_to(np.array(pos))
    np.testing.assert_allclose(bunny.to_world, pose.matrix() @ rest.to_world, atol=1e-9)
    assert (studio_engine.save_dir / "from_browser.png").is_file()


def test_scale_and_rotate_sliders_exposure_and_layers(page, studio_engine):
    before = _snapshot(studio_engine)["mask"].sum()
    page.fill("#scale", "1")  # log2 scale: 2×
    page.wait_for_function("window.studio.header.objects.bunny.scale === 2 && "
                           "!window.studio.header.superseded", timeout=TIMEOUT_MS)
    ratio = _snapshot(studio_engine)["mask"].sum() / before
    assert 3.0 < ratio < 5.0, ratio  # twice the size: about four times the area
    page.fill("#yaw", "90")
    page.wait_for_function("window.studio.header.objects.bunny.yaw_deg === 90",
                           timeout=TIMEOUT_MS)
    page.click("#layers input[value=mask]")
    page.wait_for_function("window.studio.header.layer === 'mask'", timeout=TIMEOUT_MS)
    mask = _canvas(page)
    grey = mask.mean(axis=2)
    assert (grey > 200).mean() > 0.01 and (grey < 30).mean() > 0.8  # object, white on black
    page.click("#layers input[value=composite]")
    page.fill("#exposure", "2")
    page.wait_for_function("window.studio.header.exposure === 2 && "
                           "window.studio.header.layer === 'composite'", timeout=TIMEOUT_MS)
    assert page.inner_text("#exposure-out") == "+2.0 EV"
    page.fill("#exposure", "0")
    page.fill("#scale", "0")
    page.fill("#yaw", "0")
    page.wait_for_function("window.studio.header.objects.bunny.scale === 1 && "
                           "window.studio.header.objects.bunny.yaw_deg === 0 && "
                           "window.studio.header.exposure === 0", timeout=TIMEOUT_MS)
    assert not page.errors


def test_saving_over_a_file_the_studio_did_not_write_asks_first(page, studio_engine,
                                                               tmp_path, monkeypatch):
    """The page sends ``overwrite`` only after the user confirmed: dismissed, the user's
    file stays byte for byte; accepted, it is replaced. Its own earlier save is replaced
    without a question."""
    monkeypatch.setattr(studio_engine, "save_dir", tmp_path.resolve())
    user = tmp_path / "theirs.png"
    user.write_bytes(b"a user's picture")
    asked: list[str] = []
    answer = {"accept": False}

    def on_dialog(dialog):
        asked.append(dialog.message)
        dialog.accept() if answer["accept"] else dialog.dismiss()

    page.on("dialog", on_dialog)
    try:
        page.evaluate("window.studio.errors = []")
        page.fill("#save-name", "theirs")
        page.click("#save")
        page.wait_for_function("window.studio.errors.length >= 1", timeout=TIMEOUT_MS)
        page.wait_for_timeout(500)  # a wrong page would send the overwrite now
        assert len(asked) == 1 and "theirs.png" in asked[0]
        assert user.read_bytes() == b"a user's picture"
        assert not (tmp_path / "theirs.toml").exists()
        answer["accept"] = True
        page.click("#save")
        page.wait_for_function("document.getElementById('saved').textContent"
                               ".includes('theirs.toml')", timeout=TIMEOUT_MS)
        assert len(asked) == 2 and user.read_bytes() != b"a user's picture"
        page.evaluate("document.getElementById('saved').textContent = ''")
        page.click("#save")  # now this studio's own file: no question
        page.wait_for_function("document.getElementById('saved').textContent"
                               ".includes('theirs.toml')", timeout=TIMEOUT_MS)
        assert len(asked) == 2
    finally:
        page.remove_listener("dialog", on_dialog)
