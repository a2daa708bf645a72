"""Animations: the rasteriser against `shade`, the files imageio reads back, the command."""

import subprocess
import sys
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from command_line import fails

import diffbody as db
from diffbody._render import _REGION_COLOURS, _region, shade
from diffbody.cli._main import main
from diffbody.viewer._animate import DEFAULT_FPS, Raster, animate, frame_rate

N = 5  # frames: every test animates this many, so the vmapped forward compiles once
SIZE = (128, 160)  # (width, height) px
TIMES = np.arange(N) * 0.2  # s: 5 fps
CAPTION_ROWS = 24  # px from the top: the caption ("t = 0.20 s"), fontsize 10 at 100 dpi


def _colours(body):
    return np.array(
        [_REGION_COLOURS[_region(body.segment_names[s])] for s in np.asarray(body.sphere_segment)]
    )


@pytest.fixture(scope="module")
def poses(male50):
    """Frames 0 and 1 the standard position; then the left arm rises and the body steps
    forward, 0.2 m a frame."""
    rest = male50.rest_pose()
    arm = male50.segment_index("left_upper_arm")
    frames = [
        db.Pose(rest.position + jnp.asarray([step, 0.0, 0.0]), rest.angles.at[arm, 1].add(lift))
        for step, lift in zip([0.0, 0.0, 0.2, 0.4, 0.6], [0.0, 0.0, 0.6, 1.2, 1.8])
    ]
    return jax.tree.map(lambda *a: jnp.stack(a), *frames)  # leading frame axis


@pytest.mark.parametrize("view", ["front", "perspective", (30.0, 20.0)])
def test_raster_is_shade(male50, fk_male50, view):
    """`shade`'s picture on `shade`'s own canvas: the same pixels covered, by the same
    spheres (float64: the same arithmetic), and their colours to rounding."""
    fk = fk_male50(male50.rest_pose())
    centers, radii = np.asarray(fk.sphere_centers), np.asarray(fk.sphere_radii)
    colours = _colours(male50)
    image, extent = shade(centers, radii, colours, view, 150.0)
    raster = Raster.build(radii, colours, view, 150.0, (extent[0], extent[2]), image.shape[:2])
    mine = raster.image(centers)
    np.testing.assert_array_equal(mine[..., 3], image[..., 3])
    np.testing.assert_allclose(mine, image, rtol=0, atol=1e-4)


def test_raster_supersampled_is_the_block_mean(male50, fk_male50):
    """supersample=2: each pixel the mean of its 2 x 2 block at twice the resolution, the
    colours weighted by their coverage."""
    fk = fk_male50(male50.rest_pose())
    centers, radii = np.asarray(fk.sphere_centers), np.asarray(fk.sphere_radii)
    fine = Raster.build(radii, _colours(male50), "left", 120.0, (-0.4, -0.1), (240, 120))
    big = fine.image(centers).astype(float)
    small = fine.image(centers, supersample=2)
    blocks = big.reshape(120, 2, 60, 2, 4)
    alpha = blocks[..., 3].mean(axis=(1, 3))
    rgb = (blocks[..., :3] * blocks[..., 3:]).mean(axis=(1, 3)) / np.maximum(alpha, 1e-9)[..., None]
    np.testing.assert_allclose(small[..., 3], alpha, atol=1e-6)
    inside = alpha > 0
    np.testing.assert_allclose(small[inside][:, :3], rgb[inside], atol=1e-5)
    assert 0.05 < inside.mean() < 0.9 and np.any((alpha > 0) & (alpha < 1))  # soft outlines


def _read(path, size=SIZE) -> np.ndarray:
    """(frames, rows, columns, 3) RGB of an animation of `size` (w, h), 0-255: a GIF through
    imageio, a video decoded by imageio-ffmpeg's ffmpeg to raw RGB (imageio's own reader
    leaves ffmpeg's pipes open)."""
    if str(path).endswith(".gif"):
        import imageio.v3 as iio

        return iio.imread(path)[..., :3].astype(float)
    import imageio_ffmpeg

    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path)]
    command += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-"]
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)  # fork + exec of ffmpeg
        raw = subprocess.run(command, capture_output=True, check=True).stdout
    w, h = size
    return np.frombuffer(raw, np.uint8).reshape(-1, h, w, 3).astype(float)


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_animate_writes_every_frame(male50, poses, tmp_path, suffix):
    path = animate(male50, poses, tmp_path / f"walk{suffix}", times=TIMES, size=SIZE)
    frames = _read(path)
    assert frames.shape == (N, SIZE[1], SIZE[0], 3)
    below = frames[:, CAPTION_ROWS:]  # the caption (the time) differs in every frame
    # Frames 0 and 1 hold one pose; each later frame another (GIF: one palette per frame;
    # H.264: lossy), and much of each picture is the blank background.
    still = np.abs(below[1] - below[0]).mean()
    moved = [np.abs(below[i + 1] - below[i]).mean() for i in range(1, N - 1)]
    assert still < 0.5 and min(moved) > 5 * max(still, 0.2)
    body = below.min(axis=-1) < 200  # shaded spheres are darker than the floor and the page
    assert 0.02 < body.mean() < 0.5
    # The body walks right to left across a fixed camera (+X is to the left in "perspective").
    columns = [np.nonzero(b.any(axis=0))[0].mean() for b in body]
    assert np.all(np.diff(columns[1:]) < 0)


def test_animate_frame_rate(male50, poses, tmp_path):
    import imageio.v3 as iio

    assert frame_rate(TIMES, N) == pytest.approx(5.0)
    assert frame_rate(None, N) == frame_rate(TIMES[::-1], N) == DEFAULT_FPS
    gif = animate(male50, poses, tmp_path / "a.gif", times=TIMES, size=SIZE)
    assert iio.immeta(gif)["duration"] == 200  # ms per frame
    gif = animate(male50, poses, tmp_path / "b.gif", fps=20, size=SIZE, view="left")
    assert iio.immeta(gif)["duration"] == 50


def test_animate_refuses_bad_input(male50, poses, tmp_path, monkeypatch):
    with pytest.raises(ValueError, match=r"unknown extension '\.avi'.*\.mp4 or \.gif"):
        animate(male50, poses, tmp_path / "walk.avi")
    with pytest.raises(ValueError, match="even numbers"):
        animate(male50, poses, tmp_path / "walk.gif", size=(101, 80))
    with pytest.raises(ValueError, match="unknown view"):
        animate(male50, poses, tmp_path / "walk.gif", view="below")
    with pytest.raises(ValueError, match="3 times for 5 frames"):
        animate(male50, poses, tmp_path / "walk.gif", times=[0.0, 1.0, 2.0])
    with pytest.raises(TypeError, match="PoseRecord"):
        animate(male50, poses.angles, tmp_path / "walk.gif")
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    with pytest.raises(ImportError, match=r"needs imageio; pip install 'diffbody\[view\]'"):
        animate(male50, poses, tmp_path / "walk.gif")
    assert not (tmp_path / "walk.gif").exists()


def test_animate_command(male50, poses, tmp_path, capsys):
    pose_file = db.save_pose(tmp_path / "walk.json", male50, poses, times=TIMES)
    out = tmp_path / "walk.gif"
    argv = ["animate", str(pose_file), "--out", str(out), "--view", "left", "--fps", "10"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}: 5 frames" in printed and "10 fps" in printed and "per frame" in printed
    assert _read(out, (640, 480)).shape == (N, 480, 640, 3)
    err = fails(["animate", str(pose_file), "--out", str(tmp_path / "walk.avi")], capsys)
    assert "--out" in err and ".mp4 or .gif" in err
    err = fails(["animate", str(tmp_path / "none.json"), "--out", str(out)], capsys)
    assert "none.json" in err
