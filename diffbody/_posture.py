"""Analytic posture from joint positions, and the standard orientation as a post-projection
(seed 000, "Standard Orientation"; docs/design.md, sections 3 and 4).

"Whenever the limbs are placed into a position by specifying the joint positions, the
resulting orientation of the segments is computed and compared to the orientation given by
the standard orientation function, and the segments are then adjusted to agree with the
default orientation. If an orientation different from the default is desired, then a
further adjustment is made." (seed 000)
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._body import Body, Pose
from ._chain import walk_below_top
from ._kinematics import KINDS, forward, socket_frame_of_kind
from ._orientation import vector_to_azimuth_polar
from ._rotations import rot_z, safe_atan2, safe_normalize, swing_rotation


def _triad(a1: Array, a2: Array) -> Array:
    """An orthonormal frame (columns) from two non-parallel vectors."""
    x = safe_normalize(a1, jnp.asarray([1.0, 0.0, 0.0]))
    z = safe_normalize(jnp.cross(a1, a2), jnp.asarray([0.0, 0.0, 1.0]))
    return jnp.stack([x, jnp.cross(z, x), z], axis=-1)


def whole_body_rotation(body: Body, p: Array) -> Array:
    """The whole body's world rotation from the segments leaving the (default) root joint:
    the triad of the first two whose standard directions are not parallel (exact for
    consistent data), or the smallest rotation of a single one."""
    kids = [i for i, q in enumerate(body.parent) if q == 0]
    R_rest = np.asarray(body.R_socket_rest)
    vec = {i: p[body.distal_joint[i]] - p[body.proximal_joint[i]] for i in kids}
    for a in kids:
        for b in kids:
            if np.linalg.norm(np.cross(R_rest[a][:, 2], R_rest[b][:, 2])) > 0.1:
                rest = _triad(jnp.asarray(R_rest[a][:, 2]), jnp.asarray(R_rest[b][:, 2]))
                return _triad(vec[a], vec[b]) @ rest.T
    d0 = jnp.asarray(R_rest[kids[0]][:, 2])
    return swing_rotation(d0, safe_normalize(vec[kids[0]], d0))


def angles_of_rotation(R: Array) -> Array:
    """(theta, phi, tau) of the whole body (swing default about +Z) for a world rotation."""
    theta, phi, _ = vector_to_azimuth_polar(R[:, 2])
    M = swing_rotation(jnp.asarray([0.0, 0.0, 1.0], R.dtype), R[:, 2]).T @ R
    return jnp.stack([theta, phi, safe_atan2(M[1, 0], M[0, 0])])


def pose_from_joint_positions(
    body: Body,
    joint_positions: Float[ArrayLike, "n_joint 3"],
    deviation: Float[ArrayLike, " n_seg"] | None = None,
) -> Pose:
    """The analytic posture that reproduces measured joint positions (docs/design.md, section 3).

    Walking the tree from the root, each segment's direction is read in its socket frame,
    giving (theta, phi); its twist is set by the standard orientation, i.e. tau =
    `deviation` (zero by default). The twist at a distal joint does not move the joints
    beyond it (their directions are read in the twisted socket), so every joint position is
    reproduced exactly, whatever the deviation. The whole body's orientation comes from the
    segments leaving the root joint (for the default body: the pelvis and the two hip
    links). Measured positions are taken as they are: the result may violate joint limits
    (check with `diffbody.stop_violation`).

    Args:
        body: the body.
        joint_positions: (n_joint, 3) world positions (m), ordered as `body.joint_names`;
            row 0 ("center_of_gravity") is ignored.
        deviation: (n_seg,) twists away from the standard orientation (rad); default zero.

    Returns:
        A `Pose`; differentiable in the positions away from the poles of the sockets.
    """
    p = jnp.asarray(joint_positions)
    return pose_from_joints(body, p, whole_body_rotation(body, p), deviation)


def pose_from_joints(
    body: Body, p: Array, W: Array, deviation: Float[ArrayLike, " n_seg"] | None
) -> Pose:
    """`pose_from_joint_positions` given the whole body's world rotation W (twisted frame)."""
    n = body.n_segments
    tau = jnp.zeros(n, p.dtype) if deviation is None else jnp.asarray(deviation, p.dtype)
    default = body.default_root_joint
    prox, dist = np.asarray(body.proximal_joint), np.asarray(body.distal_joint)
    kinds = np.asarray([KINDS.index(k) for k in body.standard_kind])

    def step(parent, x):
        R_twisted_parent, _ = parent
        bone, tau_i, R_parent_socket, R_rest, kind = x
        socket = R_twisted_parent @ R_parent_socket
        d_socket = socket.T @ safe_normalize(bone, socket[:, 2])
        theta, phi, _ = vector_to_azimuth_polar(d_socket)
        R_base = socket @ socket_frame_of_kind(theta, phi, R_rest, kind)
        return R_base @ rot_z(tau_i), jnp.stack([theta, phi, tau_i])

    # The whole body's twist is its stance, fixed by the positions: no deviation applies.
    top = (W, angles_of_rotation(W))
    xs = (p[dist] - p[prox], tau, body.R_parent_socket, body.R_socket_rest, jnp.asarray(kinds))
    R_twisted, angles = walk_below_top(body.parent, step, top, xs)
    position = p[default]
    if body.root_joint != default:
        # Re-rooted body: the whole body's orientation is the pinned frame's, relative to
        # its standard-position frame (see Body.with_root).
        seg = body.distal_joint.index(body.root_joint)
        angles = angles.at[0].set(angles_of_rotation(R_twisted[seg] @ body.R_world_pin_rest.T))
        position = p[body.root_joint]
    return Pose(position=position, angles=angles)


def apply_standard_orientation(
    body: Body, pose: Pose, deviation: Float[ArrayLike, " n_seg"] | None = None
) -> Pose:
    """The post-projection of seed 000: the same joint positions, with every segment's twist
    reset to its standard orientation plus `deviation` (rad, zero by default).

    Used after a solve: whatever path the solver took, the limbs end in their natural frames.
    Joint positions are unchanged (to rounding); points off the segment axes (spheres,
    features) turn with the twists.
    """
    fk = forward(body, pose)
    return pose_from_joint_positions(body, fk.joint_positions, deviation)
