"""The viewer in a real browser: headless Chromium (the system's, driven by Playwright) loads
the page, draws the body with WebGL, and the GUI's time slider moves it."""

import io
import shutil
import time

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# A software renderer, whatever the machine: headless CI has no GPU.
FLAGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
VIEWPORT = {"width": 800, "height": 600}
PANEL = 340  # px at the right edge: the floating GUI panel, left out of the comparisons


def _pixels(page) -> np.ndarray:
    """(h, w, 3) uint8 RGB of the page left of the GUI panel."""
    import matplotlib.image as mpimg

    png = page.screenshot(timeout=60_000)
    rgb = mpimg.imread(io.BytesIO(png), format="png")[..., :3]
    return np.round(255 * rgb[:, : VIEWPORT["width"] - PANEL]).astype(np.int16)


def _body_pixels(rgb: np.ndarray) -> int:
    """Pixels of the body's blue-grey clothes (blue well above red): not the white page,
    the grey grid or the skin."""
    return int(np.sum(rgb[..., 2] - rgb[..., 0] > 25))


def _until(condition, seconds: float, what: str):
    """Poll condition() until it returns something other than None; that."""
    end = time.monotonic() + seconds
    while True:
        value = condition()
        if value is not None or time.monotonic() > end:
            assert value is not None, f"timed out after {seconds} s waiting for {what}"
            return value
        time.sleep(0.25)


def test_slider_in_the_page_moves_the_body(male50, arm_raise, tmp_path):
    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (pip)")
    pytest.importorskip("viser", reason="the viewer needs viser: pip install 'diffbody[view]'")
    from diffbody.viewer import view

    poses, times = arm_raise
    with view(male50, poses, times=times, port=0) as viewer:
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
            try:
                page = browser.new_page(viewport=VIEWPORT)
                page.goto(viewer.url)
                page.wait_for_selector("canvas", timeout=60_000)

                # The scene arrives over the websocket after the page: wait for the body.
                def drawn():
                    rgb = _pixels(page)
                    return rgb if _body_pixels(rgb) > 2000 else None

                before = _until(drawn, 40, "the body to be drawn")
                thumb = page.locator("[role=slider]")
                thumb.focus()
                thumb.press("End")  # the keyboard moves the slider as a drag does
                last = viewer.n_frames - 1
                _until(lambda: True if viewer.frame == last else None, 20, "the server's frame")

                def moved():
                    rgb = _pixels(page)
                    return rgb if np.sum(np.abs(rgb - before).sum(-1) > 60) > 1000 else None

                after = _until(moved, 30, "the arms to move on the page")
            finally:
                browser.close()
    import matplotlib.image as mpimg

    mpimg.imsave(tmp_path / "frame0.png", before.astype(np.uint8))
    mpimg.imsave(tmp_path / "frame4.png", after.astype(np.uint8))
    # The page shows the body in both frames, with the arms raised in the second: the body's
    # region grows upward (smaller row indices).
    rows = [np.nonzero((p[..., 2] - p[..., 0] > 25).any(1))[0] for p in (before, after)]
    assert _body_pixels(after) > 2000
    assert rows[1].min() < rows[0].min() - 10
