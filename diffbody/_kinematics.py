"""Forward kinematics with twist propagated to the surface (seed 000, docs/design.md, section 3).

`forward` is a pure function of one body and one pose: compose it under jax.jit / jax.vmap /
jax.grad. Called eagerly (no array traced), it runs as one compiled program, cached per body
structure and array shapes. Batching is jax.vmap over poses (or bodies).
"""

import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._body import PHI, TAU, THETA, Body, Pose, without_names
from ._chain import Chain, make_chain, walk
from ._device_arrays import take
from ._orientation import (
    LIMBS,
    azimuth_polar_to_vector,
    orientation_matrix,
    standard_spin,
    standard_twist_coded,
    vector_to_azimuth_polar,
)
from ._programs import compiled, is_traced
from ._rotations import (
    eps_for,
    exp_rotvec,
    matmul3,
    matvec3,
    right_jacobian,
    rotate_about_z,
    swing_rotation,
    twist_about_z,
)
from ._spine import bend_from_rest


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
    segments use the swing default of docs/design.md, section 4: the smallest rotation taking the
    standard direction to the current one, applied to the standard-position frame.
    """
    idx = np.arange(body.n_segments) if idx is None else np.asarray(idx)
    code = table_codes(body, idx)
    theta, phi = angles[:, THETA], angles[:, PHI]

    def swing():
        R_rest = body.R_socket_rest[idx]
        d = azimuth_polar_to_vector(theta, phi)
        return matmul3(swing_rotation(R_rest[:, :, 2], d), R_rest)

    def table():  # every segment's, one evaluation: the swing default's are dropped
        return orientation_matrix(theta, phi, standard_twist_coded(theta, phi, code % len(LIMBS)))

    if np.all(code < 0):
        return swing()
    if np.all(code >= 0):
        return table()
    return jnp.where((code >= 0)[:, None, None], table(), swing())


KINDS: tuple[str, ...] = ("swing",) + LIMBS  # socket-frame kinds, coded by position


def table_codes(body: Body, idx: np.ndarray | Array) -> np.ndarray | Array:
    """(k,) the limb table of each of segments `idx` as an index into LIMBS, -1 for the
    swing default (on the host for host indices, a gather for traced ones)."""
    table = np.asarray([KINDS.index(kind) - 1 for kind in body.standard_kind], int)
    return take(table, idx).reshape(-1)


def socket_frame_of_kind(
    theta: Float[Array, ""], phi: Float[Array, ""], R_rest: Float[Array, "3 3"], kind: Array
) -> Float[Array, "3 3"]:
    """One segment's base frame in its socket (`socket_frames`) with its kind as a traced
    code into `KINDS`, for steps of a walk that runs one code for every segment: the swing
    default and the table (of the limb `kind` codes, any for the swing default) are both
    built and the segment's own is kept."""
    d = azimuth_polar_to_vector(theta, phi)
    swing = matmul3(swing_rotation(R_rest[:, 2], d), R_rest)
    limb = jnp.maximum(jnp.asarray(kind) - 1, 0)
    table = orientation_matrix(theta, phi, standard_twist_coded(theta, phi, limb))
    return jnp.where(kind == 0, swing, table)


def twist_fraction(z: Float[Array, "*b"], length: Float[Array, "*b"]) -> Float[Array, "*b"]:
    """Share of the segment's twist a point at height z turns by: z / length (seed 000,
    Fig. 7 as corrected), clipped to [0, 1] so points beyond either end turn like that end."""
    safe_length = jnp.where(length > 0, length, 1.0)
    return jnp.where(length > 0, jnp.clip(z / safe_length, 0.0, 1.0), 0.0)


def spine_deviation(body: Body, spine_target: Array) -> tuple[np.ndarray, Array, Array]:
    """Bendspine of a spine target from rest, as the swing vectors and twists of the
    segments the spine moves (their deviation from the standard position)."""
    if body.spine is None:
        raise ValueError(
            f"forward: the pose has a spine_target but body {body.name!r} has no spine database "
            '(add "spine": "spine.json" to its file, see data/SCHEMA.md)'
        )
    spine = body.spine
    seg = np.asarray([body.segment_index(s) for s in spine.segment_names])
    out = bend_from_rest(spine, spine_target)
    dev = out.angles - spine.rest  # (flexion, axial, lateral) -> w_y, tau, w_x
    return seg, jnp.stack([dev[:, 2], dev[:, 0]], axis=-1), dev[:, 1]


def exp_swing(w: Float[Array, "*b 2"]) -> Float[Array, "*b 3 3"]:
    """exp of the rotation vector (w_x, w_y, 0): a swing as a matrix, smooth at zero."""
    return exp_rotvec(jnp.concatenate([w, jnp.zeros_like(w[..., :1])], axis=-1))


def socket_frames_from_swing(
    body: Body, swing: Float[Array, "k 2"], idx: np.ndarray | Array | None = None
) -> Float[Array, "k 3 3"]:
    """Base frames in their sockets from swing vectors, without passing through (theta, phi),
    of segments `idx` (all when None): smooth at the poles of the sockets, where hanging
    limbs and the spine rest (docs/design.md, section 6).

    For the swing default the frame is R_rest exp(w). A limb with a table turns that frame
    about its own Z by the table's twist relative to it, read off at the same direction.
    """
    if not isinstance(idx, jax.Array):
        idx = np.arange(body.n_segments) if idx is None else np.asarray(idx)
    R = matmul3(body.R_socket_rest[idx], exp_swing(swing))
    return twist_about_z(R, _table_twists(body, idx, R))


def _table_twists(body: Body, idx: np.ndarray | Array, R: Array) -> Array:
    """(k,) the twist about Z that turns frames R (k, 3, 3) of segments `idx` into their
    limb tables' frames at the same direction; 0 for the swing default."""
    code = table_codes(body, idx)
    if isinstance(code, np.ndarray) and np.all(code < 0):
        return jnp.zeros(R.shape[:1], R.dtype)
    t, _ = _relative_table_twist(R, code)
    return jnp.where(code >= 0, t, 0.0)


def _relative_table_twist(
    R: Array, code: np.ndarray | Array
) -> tuple[Array, Callable[[Array], Array]]:
    """For frames R (k, 3, 3) and limb codes (k,) into LIMBS (the swing default's any): the
    twist t about Z with R Rz(t) the limb's table frame S at R's Z axis d, and t's rate as
    a function of R's body rates omega (..., k, 3).

    Every segment is evaluated at once. With F = Rz(theta) Ry(phi) at d's (theta, phi), and
    R = F Rz(alpha), S = F Rz(s): t = s - alpha, read off as the angle from R's X to S's X,
    cos(s) F e_x + sin(s) F e_y, in R's XY plane (a unit vector: finite at the poles, where
    theta is 0). Its rate is S's spin about d less R's (`standard_spin`): R turning at body
    rate omega moves d by R (omega x e_z), which is dphi along F e_x and sin(phi) dtheta
    along F e_y.
    Exactly at a pole (theta and phi with zero derivatives, as `vector_to_azimuth_polar`
    gives) S does not spin.
    """
    d = R[..., 2]
    theta, phi, _ = vector_to_azimuth_polar(d)
    s, spin_meridian, spin_parallel = standard_spin(theta, phi, code % len(LIMBS))
    ct, st, cp, sp = jnp.cos(theta), jnp.sin(theta), jnp.cos(phi), jnp.sin(phi)
    x = R[..., 0]  # R's X, in F's frame (cos alpha, sin alpha, 0)
    ca = cp * (ct * x[..., 0] + st * x[..., 1]) - sp * x[..., 2]
    sa = ct * x[..., 1] - st * x[..., 0]
    cs, ss = jnp.cos(s), jnp.sin(s)
    t = jnp.arctan2(ss * ca - cs * sa, cs * ca + ss * sa)
    at_pole = jnp.sum(d[..., :2] * d[..., :2], axis=-1) <= eps_for(d)  # as `safe_norm`

    def rate(omega: Array) -> Array:
        # R (omega x e_z) = omega_y R e_x - omega_x R e_y; R e_x is (ca, sa) in F's XY.
        along = jnp.where(at_pole, 0.0, ca * omega[..., 1] + sa * omega[..., 0])
        across = jnp.where(at_pole, 0.0, sa * omega[..., 1] - ca * omega[..., 0])
        return spin_meridian * along + spin_parallel * across - omega[..., 2]

    return t, rate


def socket_rates_from_swing(
    body: Body, swing: Float[Array, "k 2"], idx: np.ndarray | Array
) -> Float[Array, "2 k 3"]:
    """Body rates vee(R^T dR) of `socket_frames_from_swing`'s frames R per unit of w_x and
    of w_y, in closed form: R_rest exp(w) turns at J_r(w) dw (the right Jacobian); a limb
    with a table then turns about its own Z by its table twist t(w), which rotates that rate
    by Rz(t)^T and adds dt about Z (`_relative_table_twist`). `idx`: host or traced."""
    idx = idx if isinstance(idx, jax.Array) else np.asarray(idx)
    w3 = jnp.concatenate([swing, jnp.zeros_like(swing[:, :1])], axis=-1)
    rates = jnp.moveaxis(right_jacobian(w3)[:, :, :2], -1, 0)  # (2, k, 3)
    code = table_codes(body, idx)
    if isinstance(code, np.ndarray) and np.all(code < 0):
        return rates
    R = matmul3(body.R_socket_rest[idx], exp_swing(swing))
    t, rate = _relative_table_twist(R, code)
    table = code >= 0
    t, dt = jnp.where(table, t, 0.0), jnp.where(table, rate(rates), 0.0)
    c, s = jnp.cos(t), jnp.sin(t)
    x, y, z = rates[..., 0], rates[..., 1], rates[..., 2]
    return jnp.stack([c * x + s * y, c * y - s * x, z + dt], axis=-1)


def place_on_segments(
    body: Body, seg: np.ndarray | Array, local: Array, z: Array, R_base: Array, tau: Array
) -> Array:
    """Local vectors (k, 3) on segments `seg` (k,; host or traced), at heights z, turned
    by their share of the twist tau, in the world (R_base: the segments' untwisted world
    frames)."""
    turned = rotate_about_z(local, tau * twist_fraction(z, body.lengths[seg]))
    return matvec3(R_base, turned)


def feature_points(
    body: Body, f: np.ndarray | Array, R_base: Array, p_prox: Array, tau: Array
) -> tuple[Float[Array, "k 3"], Float[Array, "k 3"]]:
    """World points and normals of features `f` (k,), given their segments' untwisted world
    frames (k, 3, 3), proximal joints (k, 3) and twists (k,). Computed from the features' own
    spheres only, so a reach that needs one feature never builds the others."""
    f_sph = take(np.asarray(body.feature_sphere, int), f)
    seg = take(np.asarray(body.sphere_segment, int), f_sph)
    origins = body.sphere_origins[f_sph]
    normals = place_on_segments(body, seg, body.feature_directions[f], origins[:, 2], R_base, tau)
    centers = p_prox + place_on_segments(body, seg, origins, origins[:, 2], R_base, tau)
    return centers + body.sphere_radii[f_sph, None] * normals, normals


def forward(body: Body, pose: Pose) -> Kinematics:
    """Forward kinematics of one pose (seed 000).

    Eagerly (no argument traced) the walk runs compiled (`_programs.compiled`, one program
    per body structure, names aside): op by op its per-level scan would be traced again at
    every call. Inside a transformation it is traced inline, as any pure function.

    One walk of the tree (`diffbody._chain.walk`): a segment's socket is its parent's
    twisted frame turned by the fixed socket rotation, its base frame is the socket times
    Rz(theta) Ry(phi) Rz(s), its distal joint lies at (0, 0, length), and its children hang
    from the base frame turned by its twist tau. Surface spheres, features and
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
    if is_traced(body, pose):
        return _forward(body, pose)
    # The pose through the host: a pose a compiled solve returned (committed to its device)
    # and one built on the host would otherwise compile the same program twice.
    return _forward_compiled(without_names(body), jax.device_get(pose))


def _forward(body: Body, pose: Pose) -> Kinematics:
    R_socket_base, tau = pose_frames(body, pose)
    return forward_frames(body, R_socket_base, tau, jnp.asarray(pose.position))


# One program per body structure (names aside), kept as `_programs.compiled` keeps it.
_forward_compiled = compiled(_forward)


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


class Links(eqx.Module):
    """The world state of segments after a walk (`walk_links`), leading axis per segment."""

    R_base: Float[Array, "*k 3 3"]  # cross of axes, standard orientation, no twist
    R_twisted: Float[Array, "*k 3 3"]  # turned by the twist at the distal joint
    p_proximal: Float[Array, "*k 3"]
    p_distal: Float[Array, "*k 3"]


def link_step(parent: Links, x: tuple[Array, Array, Array]) -> Links:
    """One segment of forward kinematics (seed 000): its base frame is its parent's twisted
    frame times the fixed local rotation (socket, then direction), its distal joint lies at
    (0, 0, length), and its children hang from the base frame turned by its twist."""
    R_local, tau, length = x
    # Elementwise (`matmul3`), not a dot: faster on CPU for 3x3 frames, and XLA's HLO
    # verifier (jax 0.10.2) rejects the dot of this step under nested vmaps of a while loop.
    R_base = matmul3(parent.R_twisted, R_local)
    return Links(
        R_base=R_base,
        R_twisted=twist_about_z(R_base, tau),
        p_proximal=parent.p_distal,
        p_distal=parent.p_distal + R_base[:, 2] * length,
    )


def walk_links(
    body: Body,
    chain: Chain,
    R_socket_base: Float[Array, "k 3 3"],
    tau: Float[Array, " k"],
    bases: Links,
    segments: np.ndarray | Int[Array, " k"] | None = None,
) -> Links:
    """Forward kinematics of a chain's segments (chain order) from their base frames in
    their sockets and their twists, hanging from `bases` (one walk). `segments`: the global
    segment of each chain slot (host, or data on a limb chain, `problem._tree`); by default the
    chain's own."""
    seg = np.asarray(chain.segments, int) if segments is None else segments
    R_local = matmul3(body.R_parent_socket[seg], R_socket_base)
    return walk(chain, link_step, bases, (R_local, tau, body.lengths[seg]))


def world_base(position: Float[Array, "3"]) -> Links:
    """The environment as the base the whole body hangs from: the world frame, with the
    root joint at `position`."""
    eye = jnp.eye(3, dtype=position.dtype)[None]
    p = position[None]
    return Links(R_base=eye, R_twisted=eye, p_proximal=p, p_distal=p)


def full_chain(body: Body) -> Chain:
    """Every segment of the body, hanging from the world."""
    return _full_chain(body.parent)


@functools.cache
def _full_chain(parent: tuple[int, ...]) -> Chain:
    return make_chain(parent, range(len(parent)), [-1])


def reroot(body: Body, links: Links, position: Float[Array, "3"]) -> Links:
    """Links of the whole tree moved by the rigid motion that pins the frame ending at the
    root joint to the whole body's orientation and puts the root joint at `position` (see
    `Body.with_root`); the identity for a body with its default root."""
    if body.root_joint == body.default_root_joint:
        return links
    seg = body.distal_joint.index(body.root_joint)
    Rc = links.R_twisted[0] @ body.R_world_pin_rest @ links.R_twisted[seg].T
    offset = position - Rc @ links.p_distal[seg]
    return Links(
        R_base=matmul3(Rc, links.R_base),
        R_twisted=matmul3(Rc, links.R_twisted),
        p_proximal=links.p_proximal @ Rc.T + offset,
        p_distal=links.p_distal @ Rc.T + offset,
    )


def forward_frames(
    body: Body,
    R_socket_base: Float[Array, "n_seg 3 3"],
    tau: Float[Array, " n_seg"],
    position: Float[Array, "3"],
) -> Kinematics:
    """`forward` from each segment's base frame in its socket and its twist."""
    position = jnp.asarray(position, R_socket_base.dtype)
    links = walk_links(body, full_chain(body), R_socket_base, tau, world_base(position))
    links = reroot(body, links, position)
    R_base, p_prox = links.R_base, links.p_proximal
    joint_positions = jnp.concatenate([p_prox[:1], links.p_distal], axis=0)

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
        R_world_twisted=links.R_twisted,
        sphere_centers=centers,
        sphere_radii=body.sphere_radii,
        feature_points=features,
        feature_normals=normals,
        centroids=centroids,
        center_of_gravity=cog,
    )
