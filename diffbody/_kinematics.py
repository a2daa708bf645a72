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
from ._orientation import azimuth_polar_to_vector, standard_frame, vector_to_azimuth_polar
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
        R = R.at[k].set(standard_frame(t, p, limb))
    return R


def twist_fraction(z: Float[Array, "*b"], length: Float[Array, "*b"]) -> Float[Array, "*b"]:
    """Share of the segment's twist a point at height z turns by: z / length (seed 000,
    Fig. 7 as corrected), clipped to [0, 1] so points beyond either end turn like that end."""
    safe_length = jnp.where(length > 0, length, 1.0)
    return jnp.where(length > 0, jnp.clip(z / safe_length, 0.0, 1.0), 0.0)


def spine_deviation(body: Body, spine_target: Array) -> tuple[np.ndarray, Array, Array]:
    """Bendspine of a spine target from rest, as the swing vectors and twists of the
    segments the spine moves (their deviation from the standard position)."""
    from ._spine import bendspine

    if body.spine is None:
        raise ValueError(
            f"forward: the pose has a spine_target but body {body.name!r} has no spine database "
            '(add "spine": "spine.json" to its file, see data/SCHEMA.md)'
        )
    spine = body.spine
    seg = np.asarray([body.segment_index(s) for s in spine.segment_names])
    out = bendspine(spine, spine.rest, spine_target, initiator=spine.initiator)
    dev = out.angles - spine.rest  # (flexion, axial, lateral) -> w_y, tau, w_x
    return seg, jnp.stack([dev[:, 2], dev[:, 0]], axis=-1), dev[:, 1]


def exp_swing(w: Float[Array, "*b 2"]) -> Float[Array, "*b 3 3"]:
    """exp of the rotation vector (w_x, w_y, 0): the swing as a matrix, smooth at zero."""
    from ._rotations import eps_for, skew

    v = jnp.concatenate([w, jnp.zeros_like(w[..., :1])], axis=-1)
    a2 = jnp.sum(v * v, axis=-1)[..., None, None]
    small = a2 < jnp.sqrt(eps_for(a2))
    safe = jnp.where(small, 1.0, a2)
    a = jnp.sqrt(safe)
    s = jnp.where(small, 1.0 - a2 / 6.0, jnp.sin(a) / a)
    c = jnp.where(small, 0.5 - a2 / 24.0, (1.0 - jnp.cos(a)) / safe)
    K = skew(v)
    return jnp.eye(3, dtype=v.dtype) + s * K + c * matmul3(K, K)


def socket_frames_from_swing(
    body: Body, swing: Float[Array, "k 2"], idx: np.ndarray | None = None
) -> Float[Array, "k 3 3"]:
    """Base frames in their sockets from swing vectors, without passing through (theta, phi),
    of segments `idx` (all when None): smooth at the poles of the sockets, where hanging
    limbs and the spine rest (DESIGN 6).

    For the swing default the frame is R_rest exp(w). A limb with a table turns that frame
    about its own Z by the table's twist relative to it, read off at the same direction.
    """
    idx = np.arange(body.n_segments) if idx is None else np.asarray(idx)
    kinds = [body.standard_kind[i] for i in idx]
    R = matmul3(body.R_socket_rest[idx], exp_swing(swing))
    # The table twists are gathered into one angle per segment and applied once: an
    # in-place `R.at[k].set(f(R[k]))` was miscompiled by XLA on CPU when fused with a
    # later scatter (frames off by 1e-4 rad under jit, exact eagerly).
    twist = jnp.zeros(len(idx), R.dtype)
    for limb in sorted(set(kinds) - {"swing"}):
        k = np.flatnonzero([kind == limb for kind in kinds])
        theta, phi, _ = vector_to_azimuth_polar(R[k, :, 2])
        M = matmul3(jnp.swapaxes(R[k], -1, -2), standard_frame(theta, phi, limb))
        twist = twist.at[k].set(jnp.arctan2(M[:, 1, 0], M[:, 0, 0]))
    return twist_about_z(R, twist)


def place_on_segments(
    body: Body, seg: np.ndarray, local: Array, z: Array, R_base: Array, tau: Array
) -> Array:
    """Local vectors (k, 3) on segments `seg` (k,), at heights z, turned by their share of
    the twist tau, in the world (R_base: the segments' untwisted world frames)."""
    turned = rotate_about_z(local, tau * twist_fraction(z, body.lengths[seg]))
    return matvec3(R_base, turned)


def feature_points(
    body: Body, f: np.ndarray, R_base: Array, p_prox: Array, tau: Array
) -> tuple[Float[Array, "k 3"], Float[Array, "k 3"]]:
    """World points and normals of features `f` (k,), given their segments' untwisted world
    frames (k, 3, 3), proximal joints (k, 3) and twists (k,). Computed from the features' own
    spheres only, so a reach that needs one feature never builds the others."""
    f_sph = np.asarray(body.feature_sphere, dtype=int)[f]
    seg = np.asarray(body.sphere_segment, dtype=int)[f_sph]
    origins = body.sphere_origins[f_sph]
    normals = place_on_segments(body, seg, body.feature_directions[f], origins[:, 2], R_base, tau)
    centers = p_prox + place_on_segments(body, seg, origins, origins[:, 2], R_base, tau)
    return centers + body.sphere_radii[f_sph, None] * normals, normals


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
            it has a `spine_target`, the body's spine is bent to it from rest (Bendspine,
            initiator `body.spine.initiator`), and the segments the spine moves take those
            angles instead of their rows (built from swing vectors: smooth at rest).

    Returns:
        `Kinematics`: joint positions, frames, sphere centres and radii, feature points,
        centroids and the whole body's center of gravity.
    """
    R_socket_base, tau = pose_frames(body, pose)
    return forward_frames(body, R_socket_base, tau, jnp.asarray(pose.position))


def pose_frames(body: Body, pose: Pose) -> tuple[Float[Array, "n_seg 3 3"], Float[Array, " n_seg"]]:
    """Every segment's base frame in its socket and its twist, for a pose (the spine bent to
    the pose's spine target when it has one)."""
    angles = jnp.asarray(pose.angles)
    R_socket_base, tau = socket_frames(body, angles), angles[:, TAU]
    if pose.spine_target is not None:
        seg, w, twist = spine_deviation(body, jnp.asarray(pose.spine_target))
        R_rest = body.R_socket_rest[seg]
        R_socket_base = R_socket_base.at[seg].set(matmul3(R_rest, exp_swing(w)))
        tau = tau.at[seg].set(twist)
    return R_socket_base, tau


def forward_frames(
    body: Body,
    R_socket_base: Float[Array, "n_seg 3 3"],
    tau: Float[Array, " n_seg"],
    position: Float[Array, "3"],
) -> Kinematics:
    """`forward` from each segment's base frame in its socket and its twist (the solver's
    entry point: it builds the frames from swing vectors, see `socket_frames_from_swing`)."""
    R_parent_base = matmul3(body.R_parent_socket, R_socket_base)
    position = jnp.asarray(position, R_parent_base.dtype)
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
        return place_on_segments(body, seg, local, z, R_base[seg], tau[seg])

    sph_seg = np.asarray(body.sphere_segment, dtype=int)
    origins = body.sphere_origins
    centers = p_prox[sph_seg] + place(sph_seg, origins, origins[:, 2])
    f = np.arange(len(body.feature_names))
    f_seg = sph_seg[np.asarray(body.feature_sphere, dtype=int)]
    features, normals = feature_points(body, f, R_base[f_seg], p_prox[f_seg], tau[f_seg])
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
