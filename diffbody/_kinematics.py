"""Forward kinematics with twist propagated to the surface (seed 000, DESIGN section 3).

`forward` is a pure, un-jitted function of one body and one pose: compose it under
jax.jit / jax.vmap / jax.grad. Batching is jax.vmap over poses (or bodies).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import PHI, TAU, THETA, Body, Pose
from ._orientation import azimuth_polar_to_vector, orientation_matrix, standard_twist
from ._rotations import matmul3, matvec3, rotate_about_z, swing_rotation, twist_about_z


class Kinematics(eqx.Module):
    """Everything `forward` computes for one pose (world frame, metres)."""

    joint_positions: Float[Array, "n_joint 3"]  # joint 0 is the translating "center_of_gravity"
    R_world_base: Float[Array, "n_seg 3 3"]  # cross of axes, standard orientation, no twist
    R_world_twisted: Float[Array, "n_seg 3 3"]  # the same turned by the twist at the distal joint
    sphere_centers: Float[Array, "n_sph 3"]
    sphere_radii: Float[Array, " n_sph"]
    feature_points: Float[Array, "n_feat 3"]  # origin + radius * direction of each feature
    feature_normals: Float[Array, "n_feat 3"]  # the feature directions in the world
    centroids: Float[Array, "n_seg 3"]  # each segment's centre of mass
    center_of_gravity: Float[Array, "3"]  # of the whole body


def socket_frames(
    body: Body, angles: Float[Array, "k 3"], idx: np.ndarray | None = None
) -> Float[Array, "k 3 3"]:
    """Base frames in their sockets, Rz(theta) Ry(phi) Rz(s(theta, phi)), of segments `idx`
    (all when None) whose pose angles are `angles`.

    Limbs with a table (seed 000's left arm, its mirror, the legs) use it; all other
    segments use the swing default of DESIGN section 4: the smallest rotation taking the
    standard direction to the current one, applied to the standard-position frame.
    """
    idx = np.arange(body.n_segments) if idx is None else np.asarray(idx)
    kinds = [body.standard_kind[i] for i in idx]
    theta, phi = angles[:, THETA], angles[:, PHI]
    d = azimuth_polar_to_vector(theta, phi)
    R_rest = body.R_socket_rest[idx]
    R = matmul3(swing_rotation(R_rest[:, :, 2], d), R_rest)
    for limb in sorted(set(kinds) - {"swing"}):
        k = np.flatnonzero([kind == limb for kind in kinds])
        t, p = theta[k], phi[k]
        R = R.at[k].set(orientation_matrix(t, p, standard_twist(t, p, limb)))
    return R


def twist_fraction(z: Float[Array, "*b"], length: Float[Array, "*b"]) -> Float[Array, "*b"]:
    """Share of the segment's twist a point at height z turns by: z / length (seed 000,
    Fig. 7 as corrected), clipped to [0, 1] so points beyond either end turn like that end."""
    safe_length = jnp.where(length > 0, length, 1.0)
    return jnp.where(length > 0, jnp.clip(z / safe_length, 0.0, 1.0), 0.0)


def _bend_spine(body: Body, pose: Pose) -> Pose:
    """The pose with its vertebra rows from Bendspine of its spine target, from rest."""
    from ._spine import bendspine, with_spine_angles

    if body.spine is None:
        raise ValueError(
            f"forward: the pose has a spine_target but body {body.name!r} has no spine database "
            '(add "spine": "spine.json" to its file, see data/SCHEMA.md)'
        )
    spine = body.spine
    out = bendspine(spine, spine.rest, pose.spine_target, initiator=spine.initiator)
    return with_spine_angles(body, spine, pose, out.angles)


def forward(body: Body, pose: Pose) -> Kinematics:
    """Forward kinematics of one pose (seed 000).

    Walks the tree level by level (the levels are static): a segment's socket is its
    parent's twisted frame turned by the fixed socket rotation, its base frame is the
    socket times Rz(theta) Ry(phi) Rz(s), its distal joint lies at (0, 0, length), and its
    children hang from the base frame turned by its twist tau. Surface spheres, features and
    the centroid turn about Z by tau * z / length.

    Args:
        body: the body (its arrays may be traced: FK is differentiable in the dimensions).
        pose: `Pose` with `angles` (n_seg, 3) = (theta, phi, tau) and `position` (3,); if
            it has a `spine_target`, the body's spine is first bent to it from rest
            (Bendspine, initiator `body.spine.initiator`), replacing the vertebra rows.

    Returns:
        `Kinematics`: joint positions, frames, sphere centres and radii, feature points,
        centroids and the whole body's center of gravity.
    """
    if pose.spine_target is not None:
        pose = _bend_spine(body, pose)
    angles = jnp.asarray(pose.angles)
    tau = angles[:, TAU]
    R_parent_base = matmul3(body.R_parent_socket, socket_frames(body, angles))
    position = jnp.asarray(pose.position, R_parent_base.dtype)
    # The tree is walked level by level with one lax.scan (the levels are static and padded
    # to one width; padding reads and writes a scratch slot n): a single compiled step keeps
    # compile times short, also under jacobians and solvers.
    n = body.n_segments
    parents = np.asarray(body.parent)
    rest_levels = body.levels[1:]
    width = max((len(level) for level in rest_levels), default=1)
    idx = np.full((max(len(rest_levels), 1), width), n)
    for k, level in enumerate(rest_levels):
        idx[k, : len(level)] = level
    par = np.where(idx < n, np.append(parents, n)[idx], n)
    pad = lambda a: jnp.concatenate([a, jnp.zeros_like(a[:1])])  # noqa: E731
    R_local, tau_p, L_p = pad(R_parent_base), pad(tau), pad(body.lengths)
    R_b0 = R_parent_base[0]
    carry = (
        jnp.zeros((n + 1, 3, 3), R_b0.dtype).at[0].set(R_b0),
        jnp.zeros((n + 1, 3, 3), R_b0.dtype).at[0].set(twist_about_z(R_b0, tau[0])),
        jnp.zeros((n + 1, 3), R_b0.dtype).at[0].set(position),
        jnp.zeros((n + 1, 3), R_b0.dtype).at[0].set(position + R_b0[:, 2] * body.lengths[0]),
    )

    def level_step(carry, xs):
        R_b, R_t, p_p, p_d = carry
        i, up = xs
        Rb = matmul3(R_t[up], R_local[i])
        p_up = p_d[up]
        R_b = R_b.at[i].set(Rb)
        R_t = R_t.at[i].set(twist_about_z(Rb, tau_p[i]))
        p_p = p_p.at[i].set(p_up)
        p_d = p_d.at[i].set(p_up + Rb[:, :, 2] * L_p[i, None])
        return (R_b, R_t, p_p, p_d), None

    if rest_levels:
        carry, _ = jax.lax.scan(level_step, carry, (jnp.asarray(idx), jnp.asarray(par)))
    R_base, R_twisted, p_prox, p_dist = (a[:n] for a in carry)

    if body.root_joint != body.default_root_joint:
        # Re-rooted body: pin the frame ending at the root joint to the whole body's
        # orientation and put the root joint at `position` (see Body.with_root).
        seg = body.distal_joint.index(body.root_joint)
        Rc = R_twisted[0] @ body.R_world_pin_rest @ R_twisted[seg].T
        offset = position - Rc @ p_dist[seg]
        R_base, R_twisted = matmul3(Rc, R_base), matmul3(Rc, R_twisted)
        p_prox = p_prox @ Rc.T + offset
        p_dist = p_dist @ Rc.T + offset

    joint_positions = jnp.concatenate([p_prox[:1], p_dist], axis=0)

    def place(seg: np.ndarray, local: Array, z: Array) -> Array:
        """Local vectors on segments `seg`, at heights z, turned by their share of the twist."""
        turned = rotate_about_z(local, tau[seg] * twist_fraction(z, body.lengths[seg]))
        return matvec3(R_base[seg], turned)

    sph_seg = np.asarray(body.sphere_segment, dtype=int)
    origins = body.sphere_origins
    centers = p_prox[sph_seg] + place(sph_seg, origins, origins[:, 2])
    # Features from their own spheres, not gathered from all centres: a caller that needs
    # only features (a reach) then lets XLA drop the other spheres.
    f_sph = np.asarray(body.feature_sphere, dtype=int)
    f_seg = sph_seg[f_sph]
    normals = place(f_seg, body.feature_directions, origins[f_sph, 2])
    f_centers = p_prox[f_seg] + place(f_seg, origins[f_sph], origins[f_sph, 2])
    features = f_centers + body.sphere_radii[f_sph, None] * normals
    all_seg = np.arange(body.n_segments)
    centroids = p_prox + place(all_seg, body.centroids, body.centroids[:, 2])
    total = jnp.sum(body.masses)
    cog = jnp.sum(body.masses[:, None] * centroids, axis=0) / jnp.where(total > 0, total, 1.0)
    return Kinematics(
        joint_positions=joint_positions,
        R_world_base=R_base,
        R_world_twisted=R_twisted,
        sphere_centers=centers,
        sphere_radii=body.sphere_radii,
        feature_points=features,
        feature_normals=normals,
        centroids=centroids,
        center_of_gravity=cog,
    )
