"""A body as rigid links joined by hinges (docs/design.md, section 1): what the MuJoCo MJCF
(`_mjcf`) and URDF (`_urdf`) exporters share, a pose's hinge values (rad) and the links'
geometry (float64 NumPy: m, kg).

Each segment becomes three hinges: `{seg}_theta` about the socket's Z, `{seg}_phi` about the
turned Y, `{seg}_twist` about the segment's own Z with value s(theta, phi) + tau (s the
standard-orientation twist), so R_socket_twisted = Rz(theta) Ry(phi) Rz(s + tau) and the frame
after them is `forward`'s twisted frame at the proximal joint: joints and frames match
`forward` exactly. What a rigid link cannot say: spheres, sites and inertials turn with the
full twist (exact where tau = 0 and at the distal end); the limits, in swing space, are no box
in (theta, phi, twist); the inertia is a uniform solid sphere's of the enclosure radius, and
massless links get `TINY_MASS` and `TINY_INERTIA`.
"""

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

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


# --- link geometry --------------------------------------------------------------------------
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
        enclosure = np.asarray(body.enclosure_radii, np.float64)
        r = np.where(enclosure > 0, enclosure, self.lengths / 2)
        self.inertia = np.where(self.masses > 0, 0.4 * self.masses * r**2, 0.0)
        self.inertia = np.where(self.inertia > 0, self.inertia, TINY_INERTIA)
        self.link_masses = np.where(self.masses > 0, self.masses, TINY_MASS)
        origins = np.asarray(body.sphere_origins, np.float64)
        radii = np.asarray(body.sphere_radii, np.float64)
        sph_seg = np.asarray(body.sphere_segment, dtype=int)
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
