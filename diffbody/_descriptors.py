"""Bone descriptors over time (docs/design.md, section 4): for each bone of a fitted motion,
seed 001's spherical descriptors (theta, phi, r) in its parent's local coordinate system and
diffbody's own pose angles (theta, phi, tau) in its socket (rad, m), made continuous over time.

Read frame by frame both jump: the azimuth wraps at +-pi, and a bone through its pole flips its
azimuth by pi while its polar angle folds back. `unwrap_directions` takes, in each frame, the
representation of the same direction nearest the previous frame's, so the polar angle may
leave [0, pi]; within `POLE` of a pole the azimuth is held.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._body import Body, Pose, without_names
from ._body_cache import BodyCache
from ._kinematics import forward, pose_frames
from ._local_frames import bone_descriptors
from ._orientation import vector_to_azimuth_polar

POLE = np.deg2rad(2.0)  # rad: within this of a pole the azimuth is held


def _one(body: Body, pose: Pose) -> tuple[jax.Array, jax.Array]:
    """The joint positions (n_joint, 3) and the pose angles (n_seg, 3) of one pose, the
    spine's segments as its Bendspine target bends them."""
    R_socket_base, tau = pose_frames(body, pose)
    theta, phi, _ = vector_to_azimuth_polar(R_socket_base[:, :, 2])
    return forward(body, pose).joint_positions, jnp.stack([theta, phi, tau], axis=-1)


_many_jit = eqx.filter_jit(jax.vmap(_one, in_axes=(None, 0)))
# Keyed by the structure and the standard frames, all that `bone_descriptors` reads.
_BONE_DESCRIPTORS_MANY = BodyCache(("R_socket_rest",), size=16)


def _bone_descriptors_many(body: Body):
    """`bone_descriptors` over frames, compiled once per body: seed 001's frames read the
    body's standard position on the host, so the body is a constant of the compiled
    function."""
    return _BONE_DESCRIPTORS_MANY.get(
        body, None, lambda: jax.jit(jax.vmap(lambda p: bone_descriptors(body, p)))
    )


def _near(value, reference):
    """value + 2 pi k nearest reference."""
    return value + 2 * np.pi * np.round((reference - value) / (2 * np.pi))


def unwrap_directions(
    azimuth: np.ndarray, polar: np.ndarray, pole: float = POLE
) -> tuple[np.ndarray, np.ndarray]:
    """Spherical coordinates (n_frames, ...) of directions over time, made continuous
    (module docstring): per frame the representation nearest the previous frame's in
    (azimuth, polar), the azimuth held within `pole` (rad) of a pole. Returns new arrays."""
    a, p = np.array(azimuth, float), np.array(polar, float)
    if a.shape[0] == 0:
        return a, p
    defined = np.abs(np.sin(p)) >= np.sin(pole)
    # Before a direction's first defined frame, its azimuth is that frame's.
    first = np.argmax(defined, axis=0)
    before = np.arange(len(a)).reshape((-1,) + (1,) * (a.ndim - 1)) < first
    a = np.where(before, np.take_along_axis(a, first[None], axis=0), a)
    for t in range(1, len(a)):
        pa, pp = a[t - 1], p[t - 1]
        a1, p1 = _near(a[t], pa), _near(p[t], pp)
        a2, p2 = _near(a[t] + np.pi, pa), _near(-p[t], pp)
        flip = (a2 - pa) ** 2 + (p2 - pp) ** 2 < (a1 - pa) ** 2 + (p1 - pp) ** 2
        # At the pole only the polar angle counts: either sign of it is the same direction.
        flip = np.where(defined[t], flip, np.abs(p2 - pp) < np.abs(p1 - pp))
        a[t] = np.where(defined[t], np.where(flip, a2, a1), pa)
        p[t] = np.where(flip, p2, p1)
    return a, p


def descriptors(body: Body, poses: Pose) -> dict:
    """Per bone over time: seed 001's (theta, phi, r) and diffbody's own (theta, phi, tau),
    unwrapped (module docstring).

    Args:
        body: the body of the poses.
        poses: a `Pose` batched over frames (leading axis), e.g. `MotionFit.poses`.

    Returns:
        A dict: "names" (n_bones,) the bones (every segment but the whole body);
        "seed001" (n_frames, n_bones, 3): theta the inclination from the parent's x' (rad),
        phi the azimuth about it from z' (rad), r the bone's length (m) (seed 001's local
        coordinate systems, `bone_descriptors`); "angles" (n_frames, n_bones, 3): theta the
        azimuth and phi the polar angle of the bone in its socket, tau its twist (rad).
        Angles are continuous over the frames: no 2 pi wraps and no pi flips.
    """
    poses = jax.tree.map(jnp.asarray, poses)
    if poses.angles.ndim != 3:
        raise ValueError(
            f"descriptors: poses must be batched over frames, angles (n_frames, n_seg, 3); "
            f"got angles of shape {poses.angles.shape} (one pose: add a leading axis)"
        )
    anonymous = without_names(body)
    joints, angles = _many_jit(anonymous, poses)
    spherical = _bone_descriptors_many(anonymous)(joints)
    spherical, angles = (np.asarray(a, float)[:, 1:] for a in (spherical, angles))
    phi, theta = unwrap_directions(spherical[..., 1], spherical[..., 0])
    spherical = np.stack([theta, phi, spherical[..., 2]], axis=-1)
    azimuth, polar = unwrap_directions(angles[..., 0], angles[..., 1])
    tau = np.unwrap(angles[..., 2], axis=0)
    return {
        "names": body.segment_names[1:],
        "seed001": spherical,
        "angles": np.stack([azimuth, polar, tau], axis=-1),
    }
