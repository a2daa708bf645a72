"""Pictures of the sphere body: shaded spheres, like seed 000's displays, rasterised with a
depth buffer in NumPy and placed in matplotlib axes (orthographic views)."""

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._body import Body, Pose
from ._kinematics import forward

VIEWS = {  # (azimuth, elevation) of the camera, degrees; azimuth from +X toward +Y
    "front": (0.0, 0.0),
    "back": (180.0, 0.0),
    "left": (90.0, 0.0),
    "side": (90.0, 0.0),
    "right": (-90.0, 0.0),
    "top": (0.0, 90.0),
    "perspective": (35.0, 20.0),
}
View = str | tuple[float | int, float | int]  # a named view or (azimuth, elevation) in degrees
_REGION_COLOURS = {  # muted, so that the shading reads
    "skin": (0.87, 0.72, 0.60),
    "torso": (0.42, 0.55, 0.72),
    "arm": (0.55, 0.66, 0.80),
    "leg": (0.35, 0.42, 0.55),
    "foot": (0.30, 0.30, 0.33),
}


def _region(segment: str) -> str:
    if segment in ("head", "neck") or segment.endswith("hand"):
        return "skin"
    if segment.endswith("foot"):
        return "foot"
    if any(k in segment for k in ("thigh", "shank")):
        return "leg"
    if any(k in segment for k in ("arm", "clavicle")):
        return "arm"
    return "torso"


def sphere_colours(body: Body) -> np.ndarray:
    """(n_sph, 3) RGB in [0, 1]: each sphere in its segment's region colour (skin, torso,
    arm, leg, foot), as every picture, animation and the viewer draw it."""
    regions = [_region(body.segment_names[s]) for s in np.asarray(body.sphere_segment)]
    return np.array([_REGION_COLOURS[r] for r in regions])


def camera(view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Unit vectors toward the camera, screen right and screen up, and a label."""
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(
                f"render: unknown view {view!r}; use one of {sorted(VIEWS)} "
                "or (azimuth_deg, elevation_deg)"
            )
        az, el = VIEWS[view]
        label = view
    else:
        az, el = (float(v) for v in view)
        label = f"az {az:.0f}°, el {el:.0f}°"
    a, e = np.radians(az), np.radians(el)
    to_camera = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.cross(to_camera, right)
    return to_camera, right, up, label


def shade(
    centers: np.ndarray,
    radii: np.ndarray,
    colours: np.ndarray,
    view: View,
    pixels_per_metre: float,
) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The spheres as one shaded RGBA image (z-buffered per pixel, lit from the upper left of
    the screen; transparent off the body) and its extent in screen metres.

    Args:
        centers (n, 3), radii (n,): world spheres, m; colours (n, 3): their base RGB.
        view: the camera (`camera`); pixels_per_metre: the image's resolution.

    Returns:
        (h, w, 4) float RGBA, rows bottom-up; (left, right, bottom, top), m, for `imshow`.
    """
    to_camera, right, up, _ = camera(view)
    drawn = np.all(np.isfinite(centers), axis=1) & (radii > 0)  # nothing to draw otherwise
    centers, radii, colours = centers[drawn], radii[drawn], colours[drawn]
    if not len(radii):
        raise ValueError("shade: no sphere with a finite center and a positive radius")
    xy = np.stack([centers @ right, centers @ up], axis=-1)
    depth = centers @ to_camera
    lo = (xy - radii[:, None]).min(0)
    hi = (xy + radii[:, None]).max(0)
    w, h = np.ceil((hi - lo) * pixels_per_metre).astype(int) + 1
    image = np.zeros((h, w, 4), np.float32)
    nearest = np.full((h, w), -np.inf, np.float32)
    light = np.array([-0.4, 0.55, 0.73])
    light /= np.linalg.norm(light)
    # Pixel centres, m from the image's lower left corner.
    at = (np.arange(max(w, h), dtype=np.float32) + 0.5) / pixels_per_metre
    for c, z, r, base in zip(xy - lo, depth, radii, colours):
        x0, y0 = np.maximum(np.floor((c - r) * pixels_per_metre).astype(int), 0)
        x1, y1 = np.ceil((c + r) * pixels_per_metre).astype(int)
        dx = (at[x0 : min(x1, w)] - c[0]) / r  # (box w,), in radii
        dy = (at[y0 : min(y1, h), None] - c[1]) / r  # (box h, 1)
        nz2 = 1.0 - dx**2 - dy**2
        near = nearest[y0:y1, x0:x1]  # views: written in place
        z_front = z + r * np.sqrt(np.maximum(nz2, 0.0))
        mine = (nz2 > 0.0) & (z_front > near)
        near[mine] = z_front[mine]
        # Lambert's diffuse term with an ambient floor and a small highlight.
        nx, ny = np.broadcast_to(dx, mine.shape)[mine], np.broadcast_to(dy, mine.shape)[mine]
        lit = np.clip(nx * light[0] + ny * light[1] + np.sqrt(nz2[mine]) * light[2], 0.0, 1.0)
        rgb = np.clip(base * (0.3 + 0.75 * lit[:, None]) + 0.3 * lit[:, None] ** 12, 0.0, 1.0)
        image[y0:y1, x0:x1][mine] = np.concatenate([rgb, np.ones_like(lit)[:, None]], -1)
    extent = (lo[0], lo[0] + w / pixels_per_metre, lo[1], lo[1] + h / pixels_per_metre)
    return image, extent


def draw(
    ax,
    body: Body,
    pose: Pose,
    view: View = "front",
    *,
    features: bool = False,
    skeleton: bool = False,
    ground: bool = True,
) -> None:
    """Draw the shaded sphere body into a matplotlib Axes: one image (`shade`) at about 1.5 times
    the axes' resolution, placed in screen metres, so outlines and points drawn after it
    (`draw_cloud`) land on the body."""
    # `forward` compiles one program per body structure (names aside): scaled bodies, a
    # reach's set-up (the floor, the planted feet) and this picture share it.
    fk = forward(body, pose)
    centers = np.asarray(fk.sphere_centers, dtype=float)
    radii = np.asarray(fk.sphere_radii, dtype=float)
    to_camera, right, up, label = camera(view)
    colours = sphere_colours(body)
    xy = np.stack([centers @ right, centers @ up], axis=-1)
    lo, hi = xy.min(axis=0) - radii.max(), xy.max(axis=0) + radii.max()
    pixels = ax.get_window_extent().height  # the axes' height in the figure's pixels
    per_metre = float(np.clip(1.5 * pixels / (hi - lo).max(), 100.0, 2000.0))
    image, extent = shade(centers, radii, colours, view, per_metre)
    ax.imshow(image, extent=extent, origin="lower", interpolation="antialiased", zorder=1)
    if skeleton:
        p = np.asarray(fk.joint_positions, dtype=float)
        for i in range(1, body.n_segments):
            a, b = p[body.proximal_joint[i]], p[body.distal_joint[i]]
            ax.plot([a @ right, b @ right], [a @ up, b @ up], color="k", lw=0.8, zorder=3)
    if features:
        f = np.asarray(fk.feature_points, dtype=float)
        ax.scatter(f @ right, f @ up, s=6, color="crimson", zorder=4)
    if ground and up[2] > 0.5:  # the floor z = 0 as a line in side-on views
        ax.axhline(0.0, color="0.5", lw=0.8, zorder=0)
        lo[1] = min(lo[1], -0.05)
    pad = 0.05 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_title(label, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])
    for s in ax.spines.values():
        s.set_visible(False)


def draw_cloud(
    ax, centers: np.ndarray, radii: np.ndarray, view: View = "front", inliers=None
) -> None:
    """Draw a measured sphere cloud over a `draw`n body: each sphere as an outline in the
    same projection, outliers (`inliers` False) in red."""
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    centers, radii = np.asarray(centers, float), np.asarray(radii, float)
    _, right, up, _ = camera(view)
    xy = np.stack([centers @ right, centers @ up], axis=-1)
    inliers = np.ones(len(radii), bool) if inliers is None else np.asarray(inliers, bool)
    color = np.where(inliers[:, None], [[0.1, 0.3, 0.9, 0.8]], [[0.9, 0.1, 0.1, 0.9]])
    circles = [Circle(p, r) for p, r in zip(xy, radii)]
    ax.add_collection(PatchCollection(circles, facecolor="none", edgecolor=color, lw=0.5))
    # Grow the body's limits (set by `draw`) to the whole cloud.
    lo, hi = (xy - radii[:, None]).min(0) - 0.05, (xy + radii[:, None]).max(0) + 0.05
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    ax.set_xlim(min(x0, lo[0]), max(x1, hi[0]))
    ax.set_ylim(min(y0, lo[1]), max(y1, hi[1]))


def render(
    body: Body,
    pose: Pose,
    path: str | Path,
    view: View | Sequence[View] = "front",
    *,
    features: bool = False,
    skeleton: bool = False,
    dpi: int = 120,
    title: str | None = None,
    cloud: tuple | None = None,
) -> Path:
    """Write a PNG of the shaded sphere body in `pose`.

    Args:
        body, pose: what to draw.
        path: the PNG file to write.
        view: "front", "back", "left" (= "side"), "right", "top", "perspective", an
            (azimuth_deg, elevation_deg) pair for the camera (azimuth from +X toward +Y),
            or a list of these for several panels side by side.
        features: mark the named feature points; skeleton: draw the segment axes.
        dpi: resolution; title: a caption over the figure.
        cloud: (centers (m, 3), radii (m,)[, inliers (m,)]) of a measured sphere cloud to
            draw over the body (`draw_cloud`).

    Returns:
        The path written.
    """
    # A Figure on Agg's canvas: pyplot's global state and interactive backends are not needed.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    views = (
        [view]
        if isinstance(view, str)
        or (isinstance(view, tuple) and len(view) == 2 and not isinstance(view[0], (str, tuple)))
        else list(view)
    )
    for v in views:
        camera(v)  # an unknown view is refused before any drawing
    fig = Figure(figsize=(3.2 * len(views), 5.2), dpi=dpi)
    FigureCanvasAgg(fig)
    # Fixed margins: tight_layout would draw the whole figure once more to measure it.
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.02, top=0.88 if title else 0.94)
    axes = fig.subplots(1, len(views), squeeze=False)
    for ax, v in zip(axes[0], views):
        draw(ax, body, pose, v, features=features, skeleton=skeleton)
        if cloud is not None:
            draw_cloud(ax, cloud[0], cloud[1], v, cloud[2] if len(cloud) > 2 else None)
    if title:
        fig.suptitle(title, fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
