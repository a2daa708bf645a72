"""Pictures and the command line (the README's main job)."""

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import diffbody as db
from diffbody.cli._main import main


def _image(path):
    import matplotlib.image as mpimg

    return mpimg.imread(path)


def test_render_draws_the_body(male50, tmp_path):
    path = db.render(male50, male50.rest_pose(), tmp_path / "front.png", view="front")
    img = _image(path)
    assert img.shape[0] > 300 and img.shape[1] > 200
    # Shaded spheres: many distinct colours, and the body covers a good part of the picture.
    rgb = img[..., :3].reshape(-1, 3)
    body_pixels = np.mean(np.any(np.abs(rgb - 1.0) > 0.05, axis=1))
    assert 0.1 < body_pixels < 0.9
    assert len(np.unique(np.round(rgb, 2), axis=0)) > 50


def test_render_several_views_and_angles(male50, tmp_path):
    path = db.render(
        male50,
        male50.rest_pose(),
        tmp_path / "views.png",
        view=["front", "left", (30.0, 20.0)],
        features=True,
        skeleton=True,
    )
    one = _image(db.render(male50, male50.rest_pose(), tmp_path / "one.png"))
    assert _image(path).shape[1] > 2 * one.shape[1]


def _spheres(n: int, seed: int):
    rng = np.random.default_rng(seed)
    return rng.uniform(-0.2, 0.2, (n, 3)), rng.uniform(0.02, 0.1, n), rng.uniform(0, 1, (n, 3))


@settings(max_examples=20, deadline=None)
@given(st.integers(2, 12), st.integers(0, 2**31 - 1), st.sampled_from(["front", (30.0, 20.0)]))
def test_shade_is_a_depth_buffer(n, seed, view):
    """Each pixel shows the sphere surface nearest the camera, whatever the drawing order."""
    centers, radii, colours = _spheres(n, seed)
    image, extent = db._render.shade(centers, radii, colours, view, 400.0)
    order = np.random.default_rng(seed + 1).permutation(n)
    again, same = db._render.shade(centers[order], radii[order], colours[order], view, 400.0)
    assert same == extent
    np.testing.assert_allclose(image, again, atol=1e-6)
    # Opaque exactly over the spheres' discs (up to a pixel at the edges).
    to_camera, right, up, _ = db._render.camera(view)
    h, w = image.shape[:2]
    x = extent[0] + (np.arange(w) + 0.5) / 400.0
    y = extent[2] + (np.arange(h) + 0.5) / 400.0
    gap = (
        np.hypot(
            x[None, :, None] - (centers @ right)[None, None], y[:, None, None] - (centers @ up)
        )
        - radii
    )
    inside, outside = gap.min(-1) < -1.5 / 400.0, gap.min(-1) > 1.5 / 400.0
    assert np.all(image[inside, 3] == 1.0) and np.all(image[outside, 3] == 0.0)


def test_shade_skips_what_cannot_be_drawn():
    centers, radii, colours = _spheres(4, 0)
    image, extent = db._render.shade(centers, radii, colours, "front", 300.0)
    centers = np.concatenate([centers, [[np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    radii, colours = np.append(radii, [0.1, 0.0]), np.concatenate([colours, np.ones((2, 3))])
    again, same = db._render.shade(centers, radii, colours, "front", 300.0)
    assert same == extent and np.array_equal(image, again)
    with pytest.raises(ValueError, match="no sphere"):
        db._render.shade(centers[-2:], radii[-2:], colours[-2:], "front", 300.0)


def test_shade_lights_the_upper_left_and_keeps_the_colour():
    """One sphere seen from the front: brightest toward the light (upper left of the
    screen), darkest at the lower right rim, in the sphere's own hue."""
    image, _ = db._render.shade(
        np.zeros((1, 3)), np.array([0.1]), np.array([[0.2, 0.4, 0.8]]), "front", 500.0
    )
    lum = image[..., :3].sum(-1) * image[..., 3]
    h, w = lum.shape
    iy, ix = np.unravel_index(np.argmax(lum), lum.shape)
    assert ix < w / 2 and iy > h / 2  # rows go bottom-up
    lit = image[image[..., 3] == 1.0][:, :3]
    assert np.all(lit[:, 2] >= lit[:, 0])  # still blue, not washed out


def test_render_rejects_unknown_view(male50, tmp_path):
    with pytest.raises(ValueError, match="front"):
        db.render(male50, male50.rest_pose(), tmp_path / "x.png", view="sideways")


def test_cli_render_and_info(tmp_path, capsys):
    out = tmp_path / "body.png"
    assert main(["render", "--out", str(out), "--view", "front"]) == 0
    assert out.is_file()
    printed = capsys.readouterr().out
    assert "stature 1.75" in printed and "wrote" in printed
    assert main(["info", "--variant", "female50", "--names"]) == 0
    assert "left_hand.palm" in capsys.readouterr().out


def test_cli_reports_bad_input_clearly(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert main(["info", "--body", str(bad)]) == 2
    assert "bad.json" in capsys.readouterr().err


def test_python_dash_m_entry_point():
    out = subprocess.run(
        [sys.executable, "-m", "diffbody", "info"], capture_output=True, text=True, check=True
    )
    assert "male50" in out.stdout
