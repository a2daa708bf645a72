"""The pinhole camera of seed 003 (Webb, II B) and image sequences seen through it.

Camera frame: the centre of projection at the origin, x to the right of the image, y down,
z along the optical axis (into the scene), so the focal plane is z = f and a point (x, y, z)
is seen at (u, v) = (f x / z, f y / z) pixels from the principal point (the focal length
f in pixels). A point is in front of the camera when z > 0.

The body's world frame is X forward, Y left, Z up (docs/design.md, section 1). `look_at`
places a camera in that world: `p_camera = R_camera_world @ (p_world - p_world_camera)`.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._joint_tree import JointTree

Point = Sequence[float | int] | np.ndarray  # m, three coordinates (host side)


class Pinhole(eqx.Module):
    """A pinhole camera placed in the world: focal length (px) and pose; several cameras
    stacked along a leading view axis (`stack_cameras`)."""

    focal: Float[Array, "*v"]  # px
    R_camera_world: Float[Array, "*v 3 3"]  # world -> camera axes
    p_world_camera: Float[Array, "*v 3"]  # m, centre of projection in the world


class ImageSequence(eqx.Module):
    """What Webb's algorithm sees: image points of every joint in every frame, the depth of
    the reference joint, the focal length; and, for synthetic sequences, the truth."""

    uv: Float[Array, "*b n_frames n_obs 2"]  # px from the principal point, v down
    root_depth: Float[Array, "*b n_frames"]  # m, camera z of the reference joint
    focal: Float[Array, "*b"]  # px
    joints: Float[Array, "*b n_frames n_obs 3"] | None = None  # m, camera frame (truth)


def look_at(eye: Point, target: Point, focal: float, up: Point = (0.0, 0.0, 1.0)) -> Pinhole:
    """A camera at `eye` (m, world) whose optical axis passes through `target`, image v
    pointing along -`up` (world Z up by default)."""
    eye, target, up = (np.asarray(a, dtype=float) for a in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) == 0:
        raise ValueError("look_at: eye and target coincide; give a target away from the camera")
    z = z / np.linalg.norm(z)
    x = np.cross(-up, z)  # right = down x forward (x = y x z)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the optical axis is parallel to `up`; give another up vector")
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    check_focal(focal)
    return Pinhole(
        focal=jnp.asarray(focal, float),
        R_camera_world=jnp.asarray(np.stack([x, y, z])),
        p_world_camera=jnp.asarray(eye),
    )


def camera_around(
    target: Point, distance: float, azimuth_deg: float, height: float, focal: float
) -> Pinhole:
    """A camera `distance` m from `target` horizontally, at `azimuth_deg` from the world's
    +X (forward) toward +Y (left): 90 sees the body's left side, 0 its front. `height` is
    the camera's Z (m); it looks at `target`."""
    a = np.radians(azimuth_deg)
    target = np.asarray(target, dtype=float)
    eye = np.array([target[0] + distance * np.cos(a), target[1] + distance * np.sin(a), height])
    return look_at(eye, target, focal)


def check_focal(focal) -> None:
    """Refuse a focal length that is not a finite number > 0 (host side)."""
    f = np.asarray(focal, dtype=float)
    if not np.all(np.isfinite(f) & (f > 0)):
        raise ValueError(f"focal length must be a finite number > 0 (pixels), got {focal!r}")


def to_camera(camera: Pinhole, p_world: Float[ArrayLike, "*b 3"]) -> Float[Array, "*b 3"]:
    """World points (m) in the camera frame."""
    return (jnp.asarray(p_world) - camera.p_world_camera) @ camera.R_camera_world.T


def project(p_camera: Float[ArrayLike, "*b 3"], focal: ArrayLike) -> Float[Array, "*b 2"]:
    """(u, v) = f (x, y) / z of camera-frame points. A point at z <= 0 (behind or in the
    plane of the camera) has no image: a ValueError naming its index (eqx.error_if when
    traced)."""
    p = jnp.asarray(p_camera)
    z = p[..., 2]
    if isinstance(p, jax.core.Tracer) or isinstance(focal, jax.core.Tracer):
        p = eqx.error_if(p, jnp.any(z <= 0), "project: a point lies behind the camera (z <= 0)")
    else:
        check_focal(focal)
        bad = np.argwhere(~(np.asarray(z) > 0))
        if len(bad):
            raise ValueError(
                f"project: point {tuple(int(i) for i in bad[0])} lies behind the camera "
                f"(z = {float(np.asarray(z)[tuple(bad[0])]):.4g} m <= 0); place the camera so "
                "that every joint is in front of it"
            )
    z = jnp.where(z > 0, z, 1.0)
    return jnp.asarray(focal)[..., None] * p[..., :2] / z[..., None]


def image_sequence(
    tree: JointTree,
    camera: Pinhole,
    joints_world: Float[ArrayLike, "n_frames n_obs 3"],
    noise_px: float = 0.0,
    key: Array | None = None,
) -> ImageSequence:
    """The image sequence of joint trajectories (T, J, 3) (m, world) seen by `camera`, with
    Gaussian pixel noise of `noise_px` (standard deviation per coordinate). The reference
    joint's depth is exact (seed 003 takes it as known)."""
    joints = to_camera(camera, joints_world)
    uv = project(joints, camera.focal)
    if noise_px > 0:
        if key is None:
            raise ValueError("image_sequence: noise_px > 0 needs a PRNG key")
        uv = uv + noise_px * jax.random.normal(key, uv.shape, uv.dtype)
    return ImageSequence(
        uv=uv, root_depth=joints[:, tree.root, 2], focal=camera.focal, joints=joints
    )
