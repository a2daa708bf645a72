"""The interactive viewer: a `Scene` served as a web page by viser (three.js in the browser,
or inline in a notebook), with a time slider, play/pause, the overlays and the frame's joint
angles in a panel."""

import threading
from typing import Any

import numpy as np

from .._body import Body, Pose
from ..files._pose_file import PoseRecord
from ._scene import Scene, build_scene

INSTALL = "pip install 'diffbody[view]'"
MARKER_RADIUS = 0.012  # m, a measured marker (as `diffbody render` draws it)
TARGET_RADIUS = 0.02  # m, a reach target
MARKER_COLOUR = (20, 90, 230)
TARGET_COLOUR = (235, 110, 20)
INLIER_COLOUR = (40, 90, 220)
OUTLIER_COLOUR = (220, 30, 30)
FRAME_RATE = 10.0  # frames/s played when the frames have no times (a batch)


def _viser():
    """The viser module, or an ImportError that says how to install it."""
    try:
        import viser
    except ImportError as e:
        raise ImportError(
            f"diffbody.view needs viser, the web-based 3D viewer ({e}); install it with {INSTALL}"
        ) from None
    return viser


def _unit_sphere() -> tuple[np.ndarray, np.ndarray]:
    """(vertices (v, 3) float32, faces (f, 3) uint32) of an icosphere of radius 1: 320
    faces, round enough at a sphere's size on screen."""
    import trimesh  # a dependency of viser

    mesh = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)


def _spheres(scene_api, name: str, centers, radii, colours, **kwargs):
    """One batched mesh of spheres (one draw call for all of them)."""
    vertices, faces = _unit_sphere()
    n = len(radii)
    return scene_api.add_batched_meshes_simple(
        name,
        vertices,
        faces,
        batched_wxyzs=np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (n, 1)),
        batched_positions=np.asarray(centers, np.float32),
        batched_scales=np.asarray(radii, np.float32),
        batched_colors=np.broadcast_to(np.asarray(colours, np.uint8), (n, 3)),
        # Level-of-detail meshes are built in the browser: slow for nothing at 320 faces.
        lod="off",
        cast_shadow=False,
        receive_shadow=False,
        **kwargs,
    )


def _gaps_hidden(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(positions, scales) of points with NaN gaps: a missing one at the origin, scale 0."""
    ok = np.all(np.isfinite(points), axis=-1)
    return np.where(ok[:, None], points, 0.0), np.where(ok, radius, 0.0)


def angle_table(names: tuple[str, ...], values: np.ndarray) -> str:
    """A Markdown table of one frame's angles (degrees): joint angles with a right (_r) and a
    left (_l) value side by side, or segment angles (segment.theta, .phi, .tau) in rows."""
    cells: dict[str, dict[str, float]] = {}
    for name, value in zip(names, values):
        if "." in name:
            row, column = name.rsplit(".", 1)
        elif name.endswith(("_r", "_l")):
            row, column = name[:-2], {"_r": "right", "_l": "left"}[name[-2:]]
        else:
            row, column = name, "right"  # unsided (lumbar): in the first column
        cells.setdefault(row, {})[column] = float(value)
    columns = list(dict.fromkeys(c for row in cells.values() for c in row))
    lines = ["| | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for row, by_column in cells.items():
        # round first: no "-0.0" for a rounding error below the shown digit
        shown = [f"{round(by_column[c], 1) + 0.0:.1f}" if c in by_column else "" for c in columns]
        lines.append(f"| {row} | " + " | ".join(shown) + " |")
    return "\n".join(lines)


class Viewer:
    """A served scene: the handle `view` returns.

    Attributes:
        server: the `viser.ViserServer`.
        scene: the `Scene` drawn (every frame's spheres, the angles, the overlays).
        url: where a browser finds the page (http://host:port).
        overlays: the scene's handles of what is drawn over the body, by name ("markers",
            "cloud", "targets").
    """

    def __init__(self, server: Any, scene: Scene, url: str):
        self.server, self.scene, self.url = server, scene, url
        self._frame = -1
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._build()
        self.set_frame(0)
        self._player = None
        if scene.n_frames > 1:
            self._player = threading.Thread(target=self._play, daemon=True, name="diffbody-view")
            self._player.start()

    @property
    def n_frames(self) -> int:
        return self.scene.n_frames

    @property
    def frame(self) -> int:
        """The frame shown."""
        return self._frame

    def _build(self) -> None:
        s, scene_api, gui = self.scene, self.server.scene, self.server.gui
        scene_api.set_up_direction("+z")
        # No image-based lighting: preparing the environment map takes tens of seconds in a
        # software renderer (headless browsers, remote desktops); two lights do for spheres.
        scene_api.configure_environment_map(None)
        scene_api.configure_default_lights(enabled=False)
        scene_api.add_light_hemisphere("/light/sky", ground_color=(90, 90, 100), intensity=2.0)
        scene_api.add_light_directional("/light/key", intensity=1.5, position=(2.0, 1.0, 3.0))
        valid = np.isfinite(s.centers).all(-1)
        lo, hi = s.centers[valid].min(0), s.centers[valid].max(0)
        scene_api.add_grid("/ground", 4.0, 4.0, cell_size=0.25, position=(*(lo + hi)[:2] / 2, 0))
        # The person faces +X: the camera in front, a little to their left and above.
        middle = s.centers[0][valid[0]].mean(0)
        size = max(float(np.ptp(s.centers[0][valid[0]][:, 2])), 1.0)
        camera = self.server.initial_camera
        camera.look_at = middle
        camera.position = middle + size * np.array([1.6, 0.7, 0.25])
        camera.up = (0.0, 0.0, 1.0)

        self._body = _spheres(scene_api, "/body", s.centers[0], s.radii[0], s.colours)
        self.overlays = overlays = {}
        self._markers = self._targets = None
        if s.markers is not None:
            self._markers = _spheres(
                scene_api, "/markers", *_gaps_hidden(s.markers[0], MARKER_RADIUS), MARKER_COLOUR
            )
            overlays["markers"] = self._markers
        if s.cloud is not None:
            centers, radii, inliers = s.cloud
            colours = np.where(inliers[:, None], INLIER_COLOUR, OUTLIER_COLOUR)
            overlays["cloud"] = _spheres(
                scene_api, "/cloud", centers, radii, colours, opacity=0.35, wireframe=True
            )
        if s.targets is not None:
            self._targets = _spheres(
                scene_api, "/targets", *_gaps_hidden(s.targets[0], TARGET_RADIUS), TARGET_COLOUR
            )
            overlays["targets"] = self._targets

        self._slider = self._time = self._playing = None
        if s.n_frames > 1:
            with gui.add_folder("frames"):
                label = "row" if s.kind == "batch" else "frame"
                self._slider = gui.add_slider(label, 0, s.n_frames - 1, 1, 0)
                self._slider.on_update(lambda _: self.set_frame(int(self._slider.value)))
                if s.times is not None:
                    self._time = gui.add_text("time (s)", "", disabled=True)
                self._playing = gui.add_checkbox("play", False)
        for name, handle in overlays.items():
            box = gui.add_checkbox(name, True)
            box.on_update(lambda _, h=handle, b=box: setattr(h, "visible", b.value))
        with gui.add_folder("angles (deg)", expand_by_default=False):
            self._angles = gui.add_markdown("")

    def set_frame(self, i: int) -> None:
        """Show frame (or batch row) i, 0 <= i < n_frames; moves the slider too."""
        i = int(i)
        if not 0 <= i < self.n_frames:
            raise IndexError(f"view: frame {i} of {self.n_frames} (0 to {self.n_frames - 1})")
        s = self.scene
        with self._lock:
            if i == self._frame:
                return
            self._frame = i
            with self.server.atomic():
                self._body.batched_positions = s.centers[i].astype(np.float32)
                self._body.batched_scales = s.radii[i].astype(np.float32)
                for points, handle, radius in (
                    (s.markers, self._markers, MARKER_RADIUS),
                    (s.targets, self._targets, TARGET_RADIUS),
                ):
                    if handle is not None:
                        positions, scales = _gaps_hidden(points[i], radius)
                        handle.batched_positions = positions.astype(np.float32)
                        handle.batched_scales = scales.astype(np.float32)
                if self._time is not None:
                    self._time.value = f"{s.times[i]:.3f}"
                self._angles.content = angle_table(s.angle_names, s.angles_deg[i])
        if self._slider is not None and self._slider.value != i:
            self._slider.value = i  # its callback finds the frame shown and returns

    def _play(self) -> None:
        """Advance one frame per frame interval while "play" is ticked, looping."""
        times = self.scene.times
        steps = np.diff(times) if times is not None else np.array([])
        dt = float(np.median(steps)) if steps.size and np.all(steps > 0) else 1 / FRAME_RATE
        dt = min(max(dt, 1 / 60), 1.0)
        while not self._closed.wait(dt):
            if self._playing.value:
                self.set_frame((self._frame + 1) % self.n_frames)

    def close(self) -> None:
        """Stop playing and serving (the port is free again)."""
        self._closed.set()
        if self._player is not None:
            self._player.join()
        self.server.stop()

    def __enter__(self) -> "Viewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _repr_html_(self) -> str:
        """The live page inline in a notebook's output."""
        return f'<iframe src="{self.url}" width="100%" height="520" style="border:none"></iframe>'

    def __repr__(self) -> str:
        return f"Viewer({self.url}, {self.scene.kind}, {self.n_frames} frame(s))"


def view(
    body: Body,
    poses: Pose | PoseRecord,
    *,
    times: Any = None,
    markers: Any = None,
    cloud: Any = None,
    targets: Any = None,
    port: int = 8080,
    host: str = "127.0.0.1",
    title: str | None = None,
) -> Viewer:
    """Open an interactive 3D view of the sphere body in the browser (viser), and return at
    once.

    Every frame's spheres are computed first (one compiled, vmapped `forward`); the page
    then shows the body coloured by region, a time slider with play/pause for a sequence or
    a batch, the overlays, and the frame's joint angles in a panel. In a notebook the
    returned `Viewer` displays the page inline; elsewhere open `Viewer.url`.

    Args:
        body: the body the poses belong to.
        poses: a `Pose`, a sequence or batch of poses (a leading axis), or a `PoseRecord`
            (`load_pose`: its times and overlays are drawn unless given here).
        times: (n,) s, a sequence's frame times.
        markers: (m, 3) or (n, m, 3) m, measured markers (NaN: missing).
        cloud: (centers (c, 3), radii (c,)[, inliers (c,) bool]) m, a measured sphere cloud
            (outliers in red).
        targets: (k, 3) or (n, k, 3) m, the targets of a reach (a batch: each row's).
        port: the port to serve on; taken, the next free one is used (0: any free port).
        host: the interface to serve on ("0.0.0.0": every one, for another machine).
        title: shown over the panel.

    Returns:
        a `Viewer`: .url, .set_frame(i), .close().

    Raises:
        ImportError: viser is not installed ("pip install 'diffbody[view]'").
    """
    viser = _viser()
    scene = build_scene(body, poses, times=times, markers=markers, cloud=cloud, targets=targets)
    server = viser.ViserServer(host=host, port=port, label=title or f"diffbody {body.name}")
    name = "localhost" if host in ("0.0.0.0", "::", "") else host
    try:
        return Viewer(server, scene, f"http://{name}:{server.get_port()}")
    except BaseException:
        server.stop()
        raise
