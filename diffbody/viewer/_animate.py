"""Animations of a pose sequence or batch: every frame drawn as `diffbody.render` draws the
sphere body (shaded spheres, z-buffered, seen by one orthographic camera), written with
imageio as a video (.mp4, H.264 through imageio-ffmpeg) or an animated GIF (pillow).

The camera stays where it is for the whole animation and frames the union of all frames
(a walker crosses the picture). That also makes it fast: `shade` rasterises one sphere at a
time (about 400 small NumPy calls, 0.15-0.3 s a picture), but with the scale fixed each
sphere's pixel box has the same size in every frame, so the boxes' pixels are laid out once
(`Raster`) and a frame is one compiled program over them, with `shade`'s depth test and
lighting (tests/viewer/test_animate.py compares the two pixel for pixel). The forward kinematics
of all frames is one vmapped, compiled call. One matplotlib figure serves every frame: its
floor and label are drawn once and kept, and each frame lays the body's picture over them,
pixel for pixel, and draws the caption on top (blitting).
"""

import math
import warnings
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._body import Body, Pose, without_names
from .._kinematics import forward
from .._render import View, camera, sphere_colours

FORMATS = (".mp4", ".gif")
DEFAULT_FPS = 10.0  # frames per second of a batch, whose poses have no times
# Pixels rasterised per output pixel along each axis: 2 smooths the outlines for 2.5 times
# the time; at 640 x 480 in a video the difference is slight.
SUPERSAMPLE = 1
LIGHT = np.array([-0.4, 0.55, 0.73]) / np.linalg.norm([-0.4, 0.55, 0.73])  # `shade`'s
GRID = 0.5  # m, spacing of the floor's lines in elevated views


def _sphere_centers(body: Body, poses: Pose):
    """(f, n_sph, 3) m: every frame's sphere centres, one walk per frame under vmap."""
    return jax.vmap(lambda pose: forward(body, pose).sphere_centers)(poses)


_sphere_centers_jit = eqx.filter_jit(_sphere_centers)


@dataclass(frozen=True)
class Raster:
    """Spheres of fixed radii rasterised, frame after frame, onto one fixed canvas.

    The canvas: `shape` (rows, columns) pixels of 1 / `pixels_per_metre` m, its lower left
    corner at `origin` (screen metres: the camera's right and up). Each sphere's square box
    of pixels is laid out once (`sphere`, `ox`, `oy`: one entry per pixel of every box); a
    frame only moves the boxes. Arrays are JAX's, made once: a frame passes only its
    centres.
    """

    shape: tuple[int, int]  # (rows, columns)
    basis: Array  # (3, 3) rows: the camera's right, up and toward-the-camera unit vectors
    origin: Array  # (2,) m, screen coordinates of the canvas's lower left corner
    pixels_per_metre: Array  # ()
    radii: Array  # (n,) m
    colours: Array  # (n, 3) base RGB in [0, 1]
    sphere: Array  # (F,) int32, the sphere of each box pixel
    ox: Array  # (F,) int32, column within its box
    oy: Array  # (F,) int32, row within its box

    @staticmethod
    def build(radii, colours, view: View, pixels_per_metre: float, origin, shape) -> "Raster":
        """The boxes of spheres of `radii` (m) at `pixels_per_metre`: a sphere covers at most
        ceil(2 r ppm) + 1 pixel centres along an axis, wherever its centre lies. The list is
        padded (pixels far off the canvas) to one of a few lengths, so that animations of
        similar scale share the compiled `_raster_jit`."""
        radii = np.asarray(radii, float)
        side = np.ceil(2.0 * radii * pixels_per_metre).astype(int) + 2
        sphere = np.repeat(np.arange(len(radii)), side**2)
        start = np.repeat(np.cumsum(side**2) - side**2, side**2)
        k = np.arange(len(sphere)) - start  # index within the sphere's box
        per_row = side[sphere]
        step = 2 ** max(len(sphere).bit_length() - 4, 0)  # at most 1/8 more
        pad = -len(sphere) % step
        off = np.full(pad, -(2**24))
        to_camera, right, up, _ = camera(view)
        dtype = jnp.zeros(()).dtype  # float64 where x64 is on
        return Raster(
            shape=(int(shape[0]), int(shape[1])),
            basis=jnp.asarray(np.stack([right, up, to_camera]), dtype),
            origin=jnp.asarray(origin, dtype),
            pixels_per_metre=jnp.asarray(pixels_per_metre, dtype),
            radii=jnp.asarray(radii, dtype),
            colours=jnp.asarray(colours, dtype),
            sphere=jnp.asarray(np.concatenate([sphere, np.zeros(pad, int)]), jnp.int32),
            ox=jnp.asarray(np.concatenate([k % per_row, off]), jnp.int32),
            oy=jnp.asarray(np.concatenate([k // per_row, off]), jnp.int32),
        )

    def image(self, centers, supersample: int = 1) -> np.ndarray:
        """(rows, columns, 4) / `supersample` float32 RGBA of the spheres at `centers`
        (n, 3) m, rows bottom-up, transparent off the body: `shade`'s picture on this
        canvas, each block of supersample x supersample pixels averaged into one. Spheres
        with a non-finite centre are left out."""
        out = _raster_jit(
            self.shape,
            supersample,
            jnp.asarray(centers, self.radii.dtype),
            self.basis,
            self.origin,
            self.pixels_per_metre,
            self.radii,
            self.colours,
            self.sphere,
            self.ox,
            self.oy,
        )
        return np.asarray(out)


@partial(jax.jit, static_argnums=(0, 1))
def _raster_jit(shape, supersample, centers, basis, origin, ppm, radii, colours, sphere, ox, oy):
    """`Raster.image` as one compiled program over the box pixels (`Raster`'s fields)."""
    rows, cols = shape
    finite = jnp.all(jnp.isfinite(centers), axis=1)
    p = jnp.where(finite[:, None], centers, 0.0) @ basis.T  # (right, up, toward the camera)
    xy = jnp.where(finite[:, None], p[:, :2] - origin, -1e3)  # off the canvas if not finite
    corner = jnp.floor((xy - radii[:, None]) * ppm).astype(jnp.int32)  # the box's lower left
    px, py = corner[sphere, 0] + ox, corner[sphere, 1] + oy
    r = radii[sphere]
    # Pixel centres in float32, as `shade` has them: the same pixels fall inside.
    f32 = jnp.float32
    dx = ((px.astype(f32) + 0.5) / ppm.astype(f32) - xy[sphere, 0]) / r
    dy = ((py.astype(f32) + 0.5) / ppm.astype(f32) - xy[sphere, 1]) / r
    nz2 = 1.0 - dx**2 - dy**2
    on = (nz2 > 0.0) & (px >= 0) & (px < cols) & (py >= 0) & (py < rows)
    nz = jnp.sqrt(jnp.maximum(nz2, 0.0))
    pixel = jnp.where(on, py * cols + px, rows * cols)  # out of range: dropped
    # The z-buffer: each pixel shows the surface nearest the camera (`shade` keeps its
    # depths in float32; so does this, so that the same sphere wins).
    z = (p[sphere, 2] + r * nz).astype(f32)
    nearest = jnp.full(rows * cols, -jnp.inf, f32).at[pixel].max(z, mode="drop")
    front = on & (z == nearest[jnp.minimum(pixel, rows * cols - 1)])
    # `shade`'s Lambert term with an ambient floor and a small highlight.
    lit = jnp.clip(dx * LIGHT[0] + dy * LIGHT[1] + nz * LIGHT[2], 0.0, 1.0)[:, None]
    rgb = jnp.clip(colours[sphere] * (0.3 + 0.75 * lit) + 0.3 * lit**12, 0.0, 1.0)
    rgba = jnp.concatenate([rgb, jnp.ones_like(lit)], axis=-1).astype(f32)
    image = jnp.zeros((rows * cols, 4), f32).at[jnp.where(front, pixel, rows * cols)]
    image = image.set(rgba, mode="drop").reshape(rows, cols, 4)
    if supersample > 1:  # block averages, the colours weighted by their alpha
        k = supersample
        alpha = image[..., 3:]
        weighted = jnp.concatenate([image[..., :3] * alpha, alpha], axis=-1)
        mean = weighted.reshape(rows // k, k, cols // k, k, 4).mean(axis=(1, 3))
        a = mean[..., 3:]
        image = jnp.concatenate([mean[..., :3] / jnp.where(a > 0, a, 1.0), a], axis=-1)
    return image


def _frames(record_or_poses, body: Body, times) -> tuple[Pose, np.ndarray | None]:
    """The poses with a leading frame axis, and their times (s) or None."""
    from ..files._pose_file import PoseRecord

    if isinstance(record_or_poses, PoseRecord):
        pose = record_or_poses.pose
        single = record_or_poses.kind == "pose"
        if times is None:
            times = record_or_poses.times
    elif isinstance(record_or_poses, Pose):
        pose = record_or_poses
        single = np.ndim(pose.angles) == 2
    else:
        raise TypeError(
            "animate: give a PoseRecord (diffbody.load_pose) or a Pose with a leading frame "
            f"axis, got {type(record_or_poses).__name__}"
        )
    if single:
        pose = jax.tree.map(lambda a: a[None], pose)
    shape = np.shape(pose.angles)
    if len(shape) != 3 or shape[1:] != (body.n_segments, 3):
        raise ValueError(
            f"animate: poses with angles of shape {shape}; body {body.name!r} needs "
            f"(n_frames, {body.n_segments}, 3)"
        )
    if times is not None:
        times = np.asarray(times, float)
        if times.shape != (shape[0],):
            raise ValueError(f"animate: {len(times)} times for {shape[0]} frames")
    return pose, times


def frame_rate(times: np.ndarray | None, n_frames: int) -> float:
    """Frames per second of a sequence: the mean rate of its times (s); `DEFAULT_FPS` without
    times, for a single frame, or for times that do not increase."""
    if times is None or n_frames < 2 or not np.all(np.diff(times) > 0):
        return DEFAULT_FPS
    return float((n_frames - 1) / (times[-1] - times[0]))


def _imageio(path: Path):
    """imageio's v2 API, once the packages `path`'s container needs are known to be there;
    an ImportError naming them otherwise."""
    hint = "pip install 'diffbody[view]'"
    try:
        import imageio.v2 as iio
    except ImportError:
        raise ImportError(f"animate: writing {path.name} needs imageio; {hint}") from None
    if path.suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ImportError(
                f"animate: writing {path.name} needs imageio-ffmpeg; {hint}"
            ) from None
    return iio


def _writer(iio, path: Path, fps: float):
    """An imageio writer for `path`'s container, frames appended one by one."""
    if path.suffix == ".gif":
        # Pillow keeps the delay in milliseconds, rounded to 10 ms; loop=0 loops forever.
        return iio.get_writer(path, format="GIF", mode="I", duration=1000.0 / fps, loop=0)
    # H.264 in yuv420p, which every player reads: even sides (checked), so ffmpeg need not
    # resize (macro_block_size=1 keeps imageio from doing it either).
    return iio.get_writer(
        path, format="FFMPEG", mode="I", fps=fps, codec="libx264", quality=7, macro_block_size=1
    )


def _check_size(size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size)
        ok = (w, h) == tuple(size) and min(w, h) >= 16 and w % 2 == 0 and h % 2 == 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(
            f"animate: size must be (width, height) in pixels, even numbers >= 16 (H.264 "
            f"needs even sides), got {size!r}"
        )
    return w, h


def animate(
    body: Body,
    record_or_poses,
    path: str | Path,
    *,
    view: View = "perspective",
    fps: float | int | None = None,
    size: tuple[int, int] = (640, 480),
    times=None,
) -> Path:
    """Write an animation of a sequence (or batch) of poses: each frame the shaded sphere
    body as `diffbody.render` draws it, seen by one fixed camera that frames every frame.

    Args:
        body: the body the poses belong to.
        record_or_poses: a `PoseRecord` (`diffbody.load_pose`; a single pose makes one
            frame) or a `Pose` with a leading frame axis (angles (f, n_seg, 3) rad,
            position (f, 3) m).
        path: ``*.mp4`` (H.264, needs imageio-ffmpeg) or ``*.gif`` (pillow).
        view: a named view of `diffbody.render` ("front", "left", "perspective", ...) or
            (azimuth_deg, elevation_deg).
        fps: frames per second; default the mean rate of the times, `DEFAULT_FPS` without
            them. A GIF keeps its delay in hundredths of a second, and many viewers show
            delays under 20 ms slower: use .mp4 for rates over 50 fps.
        size: (width, height) of the frames, pixels, even numbers.
        times: (f,) s, the frames' times (default the record's): the rate and the caption.

    Returns:
        The path written. Raises ValueError for another suffix, ImportError naming the
        package when imageio (or imageio-ffmpeg for .mp4) is missing.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    if path.suffix.lower() not in FORMATS:
        raise ValueError(
            f"animate: {path}: unknown extension {path.suffix!r}; give a file name ending "
            f"in {' or '.join(FORMATS)}"
        )
    path = path.with_suffix(path.suffix.lower())
    w, h = _check_size(size)
    camera(view)  # an unknown view is refused before any work
    iio = _imageio(path)
    poses, times = _frames(record_or_poses, body, times)
    n = int(poses.angles.shape[0])
    fps = frame_rate(times, n) if fps is None else float(fps)
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"animate: fps must be a finite number > 0, got {fps!r}")

    # Every frame's spheres in one compiled call; names stripped so that bodies of one
    # structure share it.
    centers = np.asarray(_sphere_centers_jit(without_names(body), poses), float)
    radii = np.asarray(body.sphere_radii, float)
    to_camera, right, up, label = camera(view)
    xy = np.stack([centers @ right, centers @ up], axis=-1)  # (f, n, 2)
    seen = np.all(np.isfinite(xy), axis=-1)
    if not seen.any():
        raise ValueError("animate: no frame has a finite pose")
    reach = radii[None, :, None]
    lo = np.min(np.where(seen[..., None], xy - reach, np.inf), axis=(0, 1))
    hi = np.max(np.where(seen[..., None], xy + reach, -np.inf), axis=(0, 1))
    side_on = bool(abs(up[2]) > 1.0 - 1e-9)  # the floor is the line z = 0 on the screen
    if side_on:
        lo[1] = min(lo[1], -0.05)
    pad = 0.05 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    # One scale for both axes: the union's box fitted into the frame, centred.
    per_metre = min(w / (hi[0] - lo[0]), h / (hi[1] - lo[1]))
    origin = (lo + hi) / 2 - np.array([w, h]) / (2 * per_metre)
    top = origin + np.array([w, h]) / per_metre
    colours = sphere_colours(body)
    k = SUPERSAMPLE
    raster = Raster.build(radii, colours, view, k * per_metre, origin, (k * h, k * w))

    # One figure for every frame: the floor and the label drawn once and kept.
    dpi = 100
    fig = Figure(figsize=(w / dpi, h / dpi), dpi=dpi, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    _draw_floor(ax, centers[seen], right, up, side_on)
    ax.set_xlim(origin[0], top[0])
    ax.set_ylim(origin[1], top[1])
    ax.set_aspect("auto")  # the limits already have the frame's proportions
    ax.text(
        0.985, 0.975, f"{body.name}, {label}", transform=ax.transAxes, va="top", ha="right",
        fontsize=8, color="0.4",
    )  # fmt: skip
    caption = ax.text(
        0.015, 0.975, "", transform=ax.transAxes, va="top", fontsize=10, animated=True
    )
    canvas.draw()
    # Agg's pixels (rows top-down), written in place: each frame is the background with
    # the body laid over it (alpha blending), then the caption drawn on top (blitting).
    pixels = np.asarray(canvas.buffer_rgba())
    background = pixels[..., :3].astype(np.float32)

    with warnings.catch_warnings():
        # imageio-ffmpeg starts ffmpeg with fork and exec; JAX warns on every fork, but the
        # child runs no Python (it only execs ffmpeg), which is safe.
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        with _writer(iio, path, fps) as writer:
            for i in range(n):
                image = raster.image(centers[i], k)[::-1]
                alpha = image[..., 3:]
                over = background * (1.0 - alpha) + 255.0 * image[..., :3] * alpha
                pixels[..., :3] = (over + 0.5).astype(np.uint8)
                caption.set_text(
                    f"t = {times[i]:.2f} s" if times is not None else f"frame {i + 1} of {n}"
                )
                fig.draw_artist(caption)
                writer.append_data(pixels[..., :3].copy())
    return path


def _draw_floor(ax, centers: np.ndarray, right, up, side_on: bool) -> None:
    """The floor z = 0 behind the body: a line in side-on views, else a grid of `GRID` m
    under the whole path (the spheres' ground-plane extent, widened by 0.5 m)."""
    if side_on:
        ax.axhline(0.0, color="0.5", lw=0.8, zorder=0)
        return
    lo = np.floor((centers[:, :2].min(0) - 0.5) / GRID) * GRID
    hi = np.ceil((centers[:, :2].max(0) + 0.5) / GRID) * GRID
    for axis in (0, 1):
        for c in np.arange(lo[axis], hi[axis] + GRID / 2, GRID):
            a, b = np.zeros(3), np.zeros(3)
            a[axis] = b[axis] = c
            a[1 - axis], b[1 - axis] = lo[1 - axis], hi[1 - axis]
            ax.plot([a @ right, b @ right], [a @ up, b @ up], color="0.82", lw=0.6, zorder=0)
