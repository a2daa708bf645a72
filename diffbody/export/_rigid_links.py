"""A body as rigid links (docs/design.md, section 1): what the MuJoCo MJCF (`_mjcf`) and
URDF (`_urdf`) exporters share, a pose's joint values (rad) and the links' geometry (float64
NumPy: m, kg).

Every segment is a rigid link whose frame is `forward`'s twisted frame at its proximal joint,
hanging from its socket: (0, 0, L_parent) in its parent's link, turned by R_parent_socket.
Its rotation in the socket (`socket_rotations_batch`) is what the joints set: a ball, three
hinges whose singularity lies outside the limits (`_limit_sets`), or the ZYZ
hinges `{seg}_theta` about the socket's Z, `{seg}_phi` about the turned Y, `{seg}_twist`
about the segment's own Z with value s(theta, phi) + tau (s the standard-orientation twist),
so R_socket_twisted = Rz(theta) Ry(phi) Rz(s + tau) (`joint_values_batch`; singular at
phi = 0 and pi, where hanging limbs rest). Joints and frames match `forward` exactly.

What a rigid link cannot say: spheres, sites and inertials turn with the full twist (exact
where tau = 0 and at the distal end). The inertia (`sphere_inertia`) is that of the
segment's surface spheres, massless links get `TINY_MASS` and `TINY_INERTIA`.
"""

import os
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from .._body import PHI, TAU, THETA, Body, Pose, rest_geometry
from .._kinematics import forward
from .._orientation import LIMBS, standard_twist

TINY_MASS = 1e-6  # kg, for massless links (the whole body, URDF's intermediate links)
TINY_INERTIA = 1e-10  # kg m^2, their (isotropic) moments of inertia
HINGES = ("theta", "phi", "twist")  # joint {seg}_{hinge}; axes z, y, z
HINGE_AXES = ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
SPHERE_RGBA = (0.85, 0.70, 0.60, 1.0)


# --- joint values ---------------------------------------------------------------------------
def _frame_rows(body: Body, pose: Pose) -> np.ndarray:
    """Segments whose hinges are read off their frames, not the pose's rows: the whole body
    of a re-rooted body (`forward` turns it to pin the root's segment) and, for a pose with a
    spine target, the segments of the spine database (`forward` replaces their rows)."""
    rows = [] if body.root_joint == body.default_root_joint else [0]
    if pose.spine_target is not None and body.spine is not None:
        rows += [body.segment_index(name) for name in body.spine.segment_names]
    return np.asarray(rows, dtype=int)


def _joint_values(body: Body, pose: Pose) -> tuple[jax.Array, jax.Array]:
    """The whole body's proximal joint (3,) (m) and every segment's hinges (theta, phi,
    twist) (n_seg, 3) (rad), with Rz(theta) Ry(phi) Rz(twist) its twisted frame in its socket.

    Everything comes from `forward`: segment i's socket is its parent's twisted frame turned
    by R_parent_socket[i] (the world's, for the whole body), which gives its base frame S and
    twisted frame T in the socket. Rows the pose sets keep its theta and phi (exact at the
    poles, where a frame cannot tell theta from twist) with twist = s(theta, phi) + tau: limbs
    take s from their table (`standard_twist`, unwrapped); swing segments read it off S, whose
    Z is the direction (theta, phi), so (Rz(theta) Ry(phi))^T S = Rz(s). Rows of
    `_frame_rows` are the ZYZ angles of T."""
    fk = forward(body, pose)
    n = body.n_segments
    up = np.where(np.asarray(body.parent) < 0, n, body.parent)
    world = jnp.eye(3, dtype=fk.R_world_twisted.dtype)[None]  # the whole body's parent
    R_world_up = jnp.concatenate([fk.R_world_twisted, world])
    R_world_socket = R_world_up[up] @ body.R_parent_socket
    S = jnp.swapaxes(R_world_socket, -1, -2) @ fk.R_world_base
    angles = jnp.asarray(pose.angles)
    theta, phi, tau = angles[:, THETA], angles[:, PHI], angles[:, TAU]
    ct, st, cp, sp = jnp.cos(theta), jnp.sin(theta), jnp.cos(phi), jnp.sin(phi)
    # Columns of Rz(theta) Ry(phi): a0 = (ct cp, st cp, -sp), a1 = (-st, ct, 0).
    m00 = ct * cp * S[:, 0, 0] + st * cp * S[:, 1, 0] - sp * S[:, 2, 0]
    m10 = -st * S[:, 0, 0] + ct * S[:, 1, 0]
    s = jnp.arctan2(m10, m00)
    for limb in LIMBS:
        k = np.flatnonzero([kind == limb for kind in body.standard_kind])
        if k.size:
            s = s.at[k].set(standard_twist(theta[k], phi[k], limb))
    hinges = jnp.stack([theta, phi, s + tau], axis=-1)
    rows = _frame_rows(body, pose)
    if rows.size:
        T = jnp.swapaxes(R_world_socket[rows], -1, -2) @ fk.R_world_twisted[rows]
        hinges = hinges.at[rows].set(jax.vmap(_zyz)(T))
    return fk.joint_positions[body.proximal_joint[0]], hinges


def _socket_rotations(body: Body, pose: Pose) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The whole body's proximal joint (3,) (m) and twisted frame in the world (3, 3), and
    every segment's twisted frame in its socket (n_seg, 3, 3), from `forward` (so a re-rooted
    body or a spine target is placed as `forward` places it)."""
    fk = forward(body, pose)
    up = np.where(np.asarray(body.parent) < 0, body.n_segments, body.parent)
    world = jnp.eye(3, dtype=fk.R_world_twisted.dtype)[None]  # the whole body's parent
    R_world_socket = jnp.concatenate([fk.R_world_twisted, world])[up] @ body.R_parent_socket
    R_socket_twisted = jnp.swapaxes(R_world_socket, -1, -2) @ fk.R_world_twisted
    return fk.joint_positions[body.proximal_joint[0]], fk.R_world_twisted[0], R_socket_twisted


@eqx.filter_jit
def socket_rotations_batch(body: Body, poses: Pose) -> tuple[jax.Array, jax.Array, jax.Array]:
    """`_socket_rotations` of poses with one leading batch axis: (k, 3), (k, 3, 3) and
    (k, n_seg, 3, 3)."""
    return jax.vmap(lambda pose: _socket_rotations(body, pose))(poses)


def rest_relative_rotations(body: Body, R_socket_twisted: np.ndarray) -> np.ndarray:
    """(..., n_seg, 3, 3) each segment's rotation from its rest frame,
    Q = R_socket_rest^T R_socket_twisted: the identity in the standard position."""
    R_rest = np.asarray(body.R_socket_rest, np.float64)
    return np.swapaxes(R_rest, -1, -2) @ np.asarray(R_socket_twisted, np.float64)


def batch_poses(name: str, body: Body, pose: Pose) -> tuple[tuple[int, ...], Pose]:
    """A pose with any leading axes as (those axes, the pose with one flat batch axis),
    its shapes checked (`name` is the caller, for the message)."""
    angles = jnp.asarray(pose.angles)
    batch = angles.shape[:-2]
    position = jnp.asarray(pose.position)
    if angles.shape[-2:] != (body.n_segments, 3) or position.shape != batch + (3,):
        raise ValueError(
            f"{name}: expected angles (..., {body.n_segments}, 3) and position (..., 3) "
            f"with the same leading axes, got {angles.shape} and {position.shape}"
        )
    flat = jax.tree.map(lambda x: jnp.reshape(x, (-1, *jnp.shape(x)[len(batch) :])), pose)
    return batch, flat


@eqx.filter_jit
def joint_values_batch(body: Body, poses: Pose) -> tuple[jax.Array, jax.Array]:
    """`_joint_values` of poses with one leading batch axis (one compile serves both
    formats)."""
    return jax.vmap(lambda pose: _joint_values(body, pose))(poses)


def _zyz(M: jax.Array) -> jax.Array:
    """(a, b, c) with M = Rz(a) Ry(b) Rz(c), b in [0, pi]; a = 0 at the poles. c is read off
    the residual (Rz(a) Ry(b))^T M = Rz(c), so it stays exact near the poles."""
    rho = jnp.hypot(M[0, 2], M[1, 2])
    b = jnp.arctan2(rho, M[2, 2])
    a = jnp.where(rho > 1e-12, jnp.arctan2(M[1, 2], M[0, 2]), 0.0)
    ca, sa, cb, sb = jnp.cos(a), jnp.sin(a), jnp.cos(b), jnp.sin(b)
    # First column of Ry(-b) Rz(-a) M, and its second row.
    r00 = cb * (ca * M[0, 0] + sa * M[1, 0]) - sb * M[2, 0]
    r10 = -sa * M[0, 0] + ca * M[1, 0]
    return jnp.stack([a, b, jnp.arctan2(r10, r00)])


# --- host-side rotations --------------------------------------------------------------------
def quat_wxyz(R: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z), w >= 0 (MuJoCo's order), of rotation matrices
    (..., 3, 3)."""
    R = np.asarray(R, np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(canonical=True, scalar_first=True)
    return q.reshape(R.shape[:-2] + (4,))


def rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF's (roll, pitch, yaw) of a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll) (fixed
    axes x, y, z), exact to rounding at and near gimbal lock (pitch = +-pi/2, e.g. a socket
    turned by a quarter turn): scipy's pitch, then yaw off R's first column where it has a
    direction (scipy sets yaw = 0 within 1e-7 of the lock, an error of that size beside
    it), then roll off the residual (Rz(yaw) Ry(pitch))^T R = Rx(roll)."""
    R = np.asarray(R, np.float64)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        _, pitch, yaw = Rotation.from_matrix(R).as_euler("xyz")
    if np.hypot(R[0, 0], R[1, 0]) > 1e-15:
        yaw = np.arctan2(R[1, 0], R[0, 0])
    M = Rotation.from_euler("ZY", [yaw, pitch]).as_matrix().T @ R
    return float(np.arctan2(M[2, 1], M[1, 1])), float(pitch), float(yaw)


# --- link geometry --------------------------------------------------------------------------
def sphere_inertia(
    masses: np.ndarray, origins: np.ndarray, radii: np.ndarray, segment: np.ndarray
) -> np.ndarray:
    """(n_seg, 3, 3) each segment's inertia tensor (kg m^2) about the centre of mass of its
    surface spheres, in its cross of axes: every sphere a uniform solid ball holding a share
    of the segment's mass proportional to its volume (overlaps counted twice), moved to that
    centre by the parallel-axis theorem,

        I = sum_k m_k (2/5 r_k^2 1 + |d_k|^2 1 - d_k d_k^T),  d_k = o_k - c.

    Zero for a segment without spheres or mass.

    Args:
        masses: (n_seg,) kg. origins: (n_sph, 3) m, in their segments' cross of axes.
        radii: (n_sph,) m. segment: (n_sph,) the segment of each sphere.
    """
    out = np.zeros((len(masses), 3, 3))
    for i, mass in enumerate(masses):
        k = np.flatnonzero(segment == i)
        if mass <= 0 or k.size == 0:
            continue
        volume = radii[k] ** 3
        m = mass * volume / volume.sum()
        d = origins[k] - m @ origins[k] / mass
        moments = 0.4 * radii[k] ** 2 + np.sum(d * d, axis=-1)
        out[i] = np.einsum("k,ij->ij", m * moments, np.eye(3)) - np.einsum("k,ki,kj->ij", m, d, d)
    return out


def xml_numbers(*values: float | int | np.floating) -> str:
    """Numbers as XML text, each exactly as the float64 it is (shortest round trip)."""
    return " ".join(repr(float(v) + 0.0) for v in values)


class Geometry:
    """The body's arrays as float64 NumPy, grouped by segment (host side, outside jit)."""

    def __init__(self, body: Body):
        self.names = body.segment_names
        self.parent = body.parent
        self.lengths = np.asarray(body.lengths, np.float64)
        self.R_parent_socket = np.asarray(body.R_parent_socket, np.float64)
        self.masses = np.asarray(body.masses, np.float64)
        self.centroids = np.asarray(body.centroids, np.float64)
        self.link_masses = np.where(self.masses > 0, self.masses, TINY_MASS)
        origins = np.asarray(body.sphere_origins, np.float64)
        radii = np.asarray(body.sphere_radii, np.float64)
        sph_seg = np.asarray(body.sphere_segment, dtype=int)
        # Inertia tensors (kg m^2) about the centroid, in the twisted frame: the spheres'
        # (`sphere_inertia`); a segment with mass but no spheres, a solid sphere of its
        # enclosure radius; massless links, `TINY_INERTIA`. The centre of mass stays the
        # body's centroid (de Leva's, which `forward`'s center of gravity uses), not the
        # spheres' own.
        self.inertia = sphere_inertia(self.masses, origins, radii, sph_seg)
        enclosure = np.asarray(body.enclosure_radii, np.float64)
        r = np.where(enclosure > 0, enclosure, self.lengths / 2)
        for i in range(body.n_segments):
            if not self.inertia[i].any():
                moment = 0.4 * self.masses[i] * r[i] ** 2
                self.inertia[i] = np.eye(3) * (moment if moment > 0 else TINY_INERTIA)
        self.spheres = [
            [(k, origins[k], radii[k]) for k in np.flatnonzero(sph_seg == i)]
            for i in range(body.n_segments)
        ]
        dirs = np.asarray(body.feature_directions, np.float64)
        self.features: list[list[tuple[str, np.ndarray]]] = [[] for _ in self.names]
        for f, (name, k) in enumerate(zip(body.feature_names, body.feature_sphere)):
            self.features[sph_seg[k]].append((name, origins[k] + radii[k] * dirs[f]))
        self.distal_joint_names = [body.joint_names[j] for j in body.distal_joint]
        # The whole body's standard-position placement (whatever joint is the root).
        p_rest, centers = rest_geometry(body)
        self.rest_origin = p_rest[body.proximal_joint[0]]
        self.R_rest_whole = self.R_parent_socket[0] @ np.asarray(body.R_socket_rest[0], np.float64)
        self.rest_centers, self.radii, self.sphere_segment = centers, radii, sph_seg

    def socket_offset(self, i: int) -> np.ndarray:
        """Position of segment i's socket in its parent's twisted frame (m)."""
        p = self.parent[i]
        return np.array([0.0, 0.0, self.lengths[p] if p >= 0 else 0.0])

    def overlapping_pairs(self) -> list[tuple[int, int]]:
        """Segment pairs (a < b, not parent and child) whose spheres overlap in the
        standard position."""
        c, r, seg = self.rest_centers, self.radii, self.sphere_segment
        d = np.linalg.norm(c[:, None] - c[None], axis=-1)
        hit = (d < r[:, None] + r[None]) & (seg[:, None] < seg[None])
        pairs = sorted({(int(seg[a]), int(seg[b])) for a, b in zip(*np.nonzero(hit))})
        return [(a, b) for a, b in pairs if self.parent[b] != a]


def write_xml(root: ET.Element, path: str | os.PathLike, comment: str) -> Path:
    root.insert(0, ET.Comment(comment))
    tree = ET.ElementTree(root)
    ET.indent(tree, space="  ")
    path = Path(path)
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return path
