"""What the viewer draws, computed once on the host before any serving: every frame's sphere
centres and radii (one vmapped, compiled `forward`), the spheres' colours, the joint angles
shown in the panel and the overlays (measured markers, a sphere cloud, reach targets).

Moving the time slider then only indexes these arrays: no kinematics runs per frame.
"""

from dataclasses import dataclass
from typing import Any

import equinox as eqx
import jax
import numpy as np

from .._body import Body, Pose, without_names
from .._joint_angles import angle_names, joint_angles
from .._kinematics import forward
from .._render import sphere_colours as region_colours
from ..files._pose_file import PoseRecord


@dataclass(frozen=True)
class Scene:
    """Every frame of a pose, a sequence or a batch, ready to draw. World frame: X forward,
    Y left, Z up; metres.

    centers: (n_frames, n_sph, 3) m, the body's sphere centres per frame.
    radii: (n_frames, n_sph) m.
    colours: (n_sph, 3) uint8 RGB, by body region (as `diffbody.render`).
    kind: "pose", "sequence" or "batch".
    times: (n_frames,) s, or None (a batch, or a sequence without times).
    angle_names: the panel's angle names; angles_deg: (n_frames, len(angle_names)) degrees.
        ISB joint angles (`joint_angles`) where the body has the segments they need, else
        each segment's (theta, phi, tau).
    markers: (n_frames, m, 3) m measured markers (NaN where a marker is missing), or None.
    cloud: (centers (c, 3) m, radii (c,) m, inliers (c,) bool) of a sphere cloud, or None.
    targets: (n_frames, k, 3) m, the targets of a reach (a batch: each row's), or None.
    """

    centers: np.ndarray
    radii: np.ndarray
    colours: np.ndarray
    kind: str
    times: np.ndarray | None
    angle_names: tuple[str, ...]
    angles_deg: np.ndarray
    markers: np.ndarray | None = None
    cloud: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    targets: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.centers.shape[0])


def sphere_colours(body: Body) -> np.ndarray:
    """(n_sph, 3) uint8 RGB: each sphere in its segment's region colour (`diffbody.render`'s)."""
    return np.round(255 * region_colours(body)).astype(np.uint8)


@eqx.filter_jit
def _spheres(body: Body, poses: Pose) -> tuple[jax.Array, jax.Array]:
    fk = jax.vmap(lambda pose: forward(body, pose))(poses)
    return fk.sphere_centers, fk.sphere_radii


@eqx.filter_jit
def _joint_angles(body: Body, poses: Pose) -> dict[str, jax.Array]:
    return jax.vmap(lambda pose: joint_angles(body, pose))(poses)


def panel_angles(body: Body, poses: Pose) -> tuple[tuple[str, ...], np.ndarray]:
    """The panel's angle names and values, (n_frames, k) degrees, of batched `poses`: the ISB
    joint angles, or each segment's (theta, phi, tau) for a body whose tree lacks the
    segments the ISB frames need (a KeyError naming the segment)."""
    try:
        angles = _joint_angles(without_names(body), poses)
    except KeyError:
        names = tuple(f"{s}.{a}" for s in body.segment_names for a in ("theta", "phi", "tau"))
        values = np.degrees(np.asarray(poses.angles, float))
        return names, values.reshape(values.shape[0], -1)
    # In `angle_names`' order (right, then left): jit returns the dict sorted by key.
    names = tuple(n for n in angle_names() if n in angles)
    return names, np.stack([np.asarray(angles[n], float) for n in names], axis=-1)


def _per_frame(points: Any, n_frames: int, what: str, field: str) -> np.ndarray | None:
    """(n_frames, m, 3) from an (m, 3) set for every frame, an (n_frames, m, 3) array or a
    pose file's overlay (its points under `field`): markers, or a batch's row targets."""
    if points is None:
        return None
    if isinstance(points, dict):
        points = points[field]
    points = np.atleast_2d(np.asarray(points, float))
    if points.ndim == 2:
        points = np.broadcast_to(points, (n_frames,) + points.shape)
    if points.ndim != 3 or points.shape[0] != n_frames or points.shape[2] != 3:
        raise ValueError(
            f"view: {what} of shape {points.shape}; expected (m, 3) or ({n_frames}, m, 3) m"
        )
    return points


def _as_cloud(cloud: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(centers (c, 3), radii (c,), inliers (c,) bool) from a tuple or a pose file's cloud
    overlay {centers, radii, inliers}; inliers default to all True."""
    if cloud is None:
        return None
    if isinstance(cloud, dict):
        cloud = (cloud["centers"], cloud["radii"], cloud.get("inliers"))
    centers, radii = np.asarray(cloud[0], float), np.asarray(cloud[1], float)
    inliers = cloud[2] if len(cloud) > 2 and cloud[2] is not None else np.ones(len(radii), bool)
    inliers = np.asarray(inliers, bool)
    if centers.shape != (len(radii), 3) or inliers.shape != radii.shape or radii.ndim != 1:
        raise ValueError(
            f"view: cloud of centers {centers.shape}, radii {radii.shape} and inliers "
            f"{inliers.shape}; expected (c, 3), (c,) and (c,)"
        )
    return centers, radii, inliers


def build_scene(
    body: Body,
    poses: Pose | PoseRecord,
    *,
    times: Any = None,
    markers: Any = None,
    cloud: Any = None,
    targets: Any = None,
) -> Scene:
    """Everything the viewer draws, for every frame.

    Args:
        body: the body the poses belong to.
        poses: a `Pose` (angles (n_seg, 3)), a sequence or batch of them (angles
            (n, n_seg, 3), position (n, 3)), or a `PoseRecord` from `load_pose`, whose
            times and overlays are used unless given here.
        times: (n,) s, the frames' times (a sequence).
        markers: (m, 3) or (n, m, 3) m, measured markers (NaN: missing), or a markers
            overlay {names, positions}.
        cloud: (centers (c, 3), radii (c,)[, inliers (c,)]) m, or a cloud overlay.
        targets: (k, 3) or (n, k, 3) m, or a targets overlay {names, points}.

    Returns:
        a `Scene`.
    """
    kind = "sequence" if times is not None else None
    if isinstance(poses, PoseRecord):
        record, poses = poses, poses.pose
        kind = record.kind
        times = record.times if times is None else times
        markers = record.overlays.get("markers") if markers is None else markers
        cloud = record.overlays.get("cloud") if cloud is None else cloud
        targets = record.overlays.get("targets") if targets is None else targets
    angles = np.shape(poses.angles)
    if angles[-2:] != (body.n_segments, 3) or len(angles) not in (2, 3):
        raise ValueError(
            f"view: pose angles of shape {angles}; expected ({body.n_segments}, 3) or "
            f"(n, {body.n_segments}, 3) for body {body.name!r}"
        )
    if len(angles) == 2:
        kind = "pose"
        poses = jax.tree.map(lambda a: a[None], poses)
    kind = kind or "batch"
    n = int(np.shape(poses.angles)[0])
    if times is not None:
        times = np.asarray(times, float)
        if times.shape != (n,):
            raise ValueError(f"view: times of shape {times.shape} for {n} frames; expected ({n},)")
    # Names are static fields but no input of the kinematics: bodies of one structure share
    # the compiled function.
    centers, radii = _spheres(without_names(body), poses)
    names, values = panel_angles(body, poses)
    return Scene(
        centers=np.asarray(centers, float),
        radii=np.asarray(radii, float),
        colours=sphere_colours(body),
        kind=kind,
        times=times,
        angle_names=names,
        angles_deg=values,
        markers=_per_frame(markers, n, "markers", "positions"),
        cloud=_as_cloud(cloud),
        targets=_per_frame(targets, n, "targets", "points"),
    )
