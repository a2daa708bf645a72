"""Local coordinate systems from measured joint positions (seed 001).

The seed builds a bone's frame from its direction and one axis of its parent's frame:
x' = bone / |bone|, y' = x' x ref, z' = x' x y' (the converted text's last line reads
"dirX x dirY"; the child's own axes are meant). When the bone nears `ref` the cross product
vanishes and the frame spins (the seed's "Caveat when choosing dirRef"). diffbody keeps the
recipe but transports the reference with the bone: `ref` is the parent axis chosen for the
bone's standard direction, carried along by the smallest rotation from the standard to the
current direction. It is then always perpendicular to the bone, so the frame is smooth and
differentiable everywhere except exactly opposite the standard direction, which joint
limits exclude (no field of frames on the sphere is smooth everywhere).
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._body import Body
from ._chain import walk_below_top
from ._orientation import vector_to_inclination_azimuth
from ._posture import whole_body_rotation
from ._rotations import safe_normalize, swing_rotation


def local_frame(
    bone: Float[ArrayLike, "*b 3"], reference: Float[ArrayLike, "*b 3"]
) -> Float[Array, "*b 3 3"]:
    """Seed 001's local coordinate system, columns (x', y', z'), in the coordinates the two
    vectors are given in: x' along the bone, y' = x' x reference, z' = x' x y'.

    Degenerate (the seed's caveat) when the bone is parallel to `reference`: y' then falls
    back to a fixed perpendicular so values stay finite, but the frame jumps there. Prefer
    `smooth_reference` for the reference.
    """
    x = safe_normalize(bone, jnp.asarray([1.0, 0.0, 0.0]))
    y = jnp.cross(x, jnp.asarray(reference))
    # Fallback for y' when bone is parallel to the reference: any perpendicular of x'.
    alt = jnp.cross(x, jnp.asarray([0.0, 0.0, 1.0]))
    alt = jnp.where(jnp.abs(x[..., 2:3]) > 0.9, jnp.cross(x, jnp.asarray([0.0, 1.0, 0.0])), alt)
    y = safe_normalize(y, safe_normalize(alt, jnp.asarray([0.0, 1.0, 0.0])))
    z = jnp.cross(x, y)
    return jnp.stack([x, y, z], axis=-1)


def smooth_reference(
    bone: Float[ArrayLike, "*b 3"],
    rest_bone: Float[ArrayLike, "*b 3"],
    rest_reference: Float[ArrayLike, "*b 3"],
) -> Float[Array, "*b 3"]:
    """A reference axis that never meets the bone: `rest_reference` (perpendicular to
    `rest_bone`) carried by the smallest rotation from `rest_bone` to `bone`. All three in
    the parent's frame; smooth except at bone = -rest_bone."""
    x = safe_normalize(bone, rest_bone)
    r0 = safe_normalize(rest_bone, jnp.asarray([1.0, 0.0, 0.0]))
    return jnp.einsum("...ij,...j->...i", swing_rotation(r0, x), jnp.asarray(rest_reference))


def _rest_references(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Per segment, the standard bone direction and its reference axis, both in the
    parent's local frame in the standard position."""
    n = body.n_segments
    R_rest = np.asarray(body.R_socket_rest)  # world frames at rest
    lcs_rest = np.zeros((n, 3, 3))
    lcs_rest[0] = np.eye(3)
    refs = np.zeros((n, 3))
    bones = np.zeros((n, 3))
    for level in body.levels[1:]:
        for i in level:
            P = lcs_rest[body.parent[i]]
            b = P.T @ R_rest[i][:, 2]
            # The parent axis least aligned with the bone (seed 001's advice), made
            # perpendicular to it.
            axis = np.eye(3)[int(np.argmin(np.abs(b)))]
            r = axis - (axis @ b) * b
            r /= np.linalg.norm(r)
            bones[i], refs[i] = b, r
            x = b
            y = np.cross(x, r)
            lcs_rest[i] = P @ np.stack([x, y, np.cross(x, y)], axis=-1)
    return bones, refs


def local_frames(
    body: Body, joint_positions: Float[ArrayLike, "n_joint 3"]
) -> Float[Array, "n_seg 3 3"]:
    """Seed 001 local coordinate systems of every segment from measured joint positions:
    world frames, columns (x', y', z'), x' along the segment. Each segment's reference is
    its parent's axis least aligned with its standard direction, transported smoothly (see
    the module docstring).

    The seed sets the root's system to the global one; diffbody uses the whole body's own
    frame, found from the segments leaving the root joint (for the default body the pelvis
    and hip links), so that every descriptor is independent of where the person stands and
    faces, which is the seed's motivation. It equals the global frame in the standard
    position.
    """
    p = jnp.asarray(joint_positions)
    bones_rest, refs_rest = (jnp.asarray(a, p.dtype) for a in _rest_references(body))
    prox, dist = np.asarray(body.proximal_joint), np.asarray(body.distal_joint)

    def step(P, x):
        bone_world, bone_rest, ref_rest = x
        bone = P.T @ bone_world  # in the parent's local system
        return P @ local_frame(bone, smooth_reference(bone, bone_rest, ref_rest))

    xs = (p[dist] - p[prox], bones_rest, refs_rest)
    return walk_below_top(body.parent, step, whole_body_rotation(body, p), xs)


def bone_descriptors(
    body: Body, joint_positions: Float[ArrayLike, "n_joint 3"]
) -> Float[Array, "n_seg 3"]:
    """Seed 001's (theta, phi, r) of every segment in its parent's local coordinate system:
    theta the inclination from x' (rad), phi the azimuth in the y'-z' plane from z' (rad),
    r the bone length (m). Row 0 (the whole body, which has no bone) is zero."""
    p = jnp.asarray(joint_positions)
    frames = local_frames(body, p)
    par = np.asarray(body.parent)
    prox, dist = np.asarray(body.proximal_joint), np.asarray(body.distal_joint)
    bone = jnp.einsum("kji,kj->ki", frames[np.maximum(par, 0)], p[dist] - p[prox])
    theta, phi, r = vector_to_inclination_azimuth(bone)
    out = jnp.stack([theta, phi, r], axis=-1)
    return out.at[0].set(0.0)
