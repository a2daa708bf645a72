"""Exporters: a body as a MuJoCo MJCF or a URDF file, and a pose as their joint values.

Both formats describe rigid links joined by one-degree-of-freedom joints, so each segment
becomes three hinges about the axes of seed 000's orientation (DESIGN section 1):

    R_socket_twisted = Rz(theta) Ry(phi) Rz(s(theta, phi) + tau)

hinge `{seg}_theta` about the socket's Z, `{seg}_phi` about the turned Y, `{seg}_twist` about
the segment's own Z, with value s(theta, phi) + tau (s the standard-orientation twist). The
frame after the three hinges is the segment's *twisted* frame (`forward`'s `R_world_twisted`),
origin at its proximal joint; a child's socket sits at (0, 0, length) in it, turned by the
fixed `R_parent_socket`. Joint positions, segment frames and the twisted frames therefore
match `diffbody.forward` exactly (to rounding; tested against MuJoCo to 1e-9).

What a rigid-body format cannot say:

- **Partial twist.** diffbody turns a surface sphere (and a feature, and the centroid) by
  tau * clip(z / length, 0, 1) about the segment axis; a rigid link carries everything
  with its one frame. Spheres, sites and inertials are placed in the twisted frame, so they
  turn by the full tau: they match `forward` exactly where tau = 0 (the standard
  orientation, which is where `apply_standard_orientation` puts every pose) and for points
  at the distal end, and drift by up to tau * (1 - z / length) * (distance from the axis)
  elsewhere.
- **Joint limits.** diffbody's limits live in swing space (a box and a cone on the swing
  vector, a hinge plane, a twist range; see `stop_violation`), which is not a box in
  (theta, phi, twist). MJCF hinges are left unlimited; URDF (which requires limits on
  revolute joints) gets theta in [-pi, pi], phi in [0, pi], twist in [-2 pi, 2 pi], which
  only keep the angles in range. Check poses with `diffbody.within_limits`.
- **Inertia.** The body holds masses and centroids, not inertia tensors. Each segment gets
  the isotropic inertia of a uniform solid sphere of its enclosure radius,
  I = 2/5 m r^2 (half its length when it has no enclosure): it spreads the mass over the
  space the segment occupies, which overestimates long segments' moments about their own axis
  and, roughly twofold, their transverse moments (de Leva 1996's radii of gyration are about
  0.3 of the length). Massless links (the whole body, URDF's intermediate links) get
  `TINY_MASS` and `TINY_INERTIA` because simulators reject zero mass on moving bodies.

The whole body (segment 0) is placed by the pose's position. In MJCF it has three slide
joints along the world axes before its three hinges; URDF has no free joint, so the URDF
fixes it at its standard-position placement (see `export_urdf`). A body re-rooted with
`Body.with_root` exports the same tree (rooted at the whole body); `mujoco_qpos` places the
whole body where `forward` puts it. Joint values are read off `forward`'s frames, so a pose
with a spine target exports its bent spine.
"""

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._body import PHI, TAU, THETA, Body, Pose, rest_geometry
from ._kinematics import forward
from ._orientation import LIMBS, standard_twist

TINY_MASS = 1e-6  # kg, for massless links (the whole body, URDF's intermediate links)
TINY_INERTIA = 1e-10  # kg m^2, their (isotropic) moments of inertia
SLIDE_AXES = ("x", "y", "z")  # MJCF: whole_body_x, whole_body_y, whole_body_z
HINGES = ("theta", "phi", "twist")  # joint {seg}_{hinge}; axes z, y, z
_HINGE_AXES = ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
URDF_LIMITS = {
    "theta": (-math.pi, math.pi),
    "phi": (0.0, math.pi),
    "twist": (-2 * math.pi, 2 * math.pi),
}
URDF_EFFORT = 1000.0  # N m, placeholder: URDF requires one; diffbody has no actuators
URDF_VELOCITY = 50.0  # rad/s, placeholder
ARMATURE = 1e-3  # kg m^2, MJCF joints: keeps MuJoCo's mass matrix regular at the poles
SPHERE_RGBA = (0.85, 0.70, 0.60, 1.0)
SITE_RGBA = (0.8, 0.1, 0.1, 1.0)
SITE_SIZE = 0.005  # m


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
def _joint_values_batch(body: Body, poses: Pose) -> tuple[jax.Array, jax.Array]:
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


def _depth_first(body: Body) -> list[int]:
    """Segments in depth-first pre-order, children in index order: the order of the nested
    MJCF bodies, hence of MuJoCo's joints and qpos."""
    order, stack = [], [0]
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(k for k in reversed(range(body.n_segments)) if body.parent[k] == i)
    return order


def mujoco_joint_names(body: Body) -> tuple[str, ...]:
    """Names of the joints of `export_mjcf`'s file in qpos order (one qpos entry each):
    whole_body_x, _y, _z, then {seg}_theta, {seg}_phi, {seg}_twist for the segments in
    depth-first order (the nesting of the file's bodies), starting with whole_body."""
    names = [f"{body.segment_names[0]}_{ax}" for ax in SLIDE_AXES]
    for i in _depth_first(body):
        names += [f"{body.segment_names[i]}_{hinge}" for hinge in HINGES]
    return tuple(names)


def mujoco_qpos(body: Body, pose: Pose) -> np.ndarray:
    """MuJoCo `qpos` of a pose, in the joint order of `export_mjcf`'s file.

    qpos = (x, y, z of the whole body's proximal joint, then for every segment: theta, phi,
    s(theta, phi) + tau), s the standard twist, so that MuJoCo's Rz(theta) Ry(phi) Rz(twist)
    is diffbody's segment frame; angles as given, not wrapped (the hinges are unlimited).
    MuJoCo orders joints as the file nests its bodies, so the segments come depth first
    (whole_body, pelvis, L5, L4, ..., then the legs), not in `body.segment_names` order:
    `mujoco_joint_names` names every entry. For a body with its default root the position
    is `pose.position`; for a re-rooted body (`Body.with_root`) the whole body's position
    and hinges are its proximal joint and twisted frame in `forward`. For a pose with a
    spine target, the segments the spine moves get the ZYZ angles of their frames in
    `forward` (their pose rows are not used). Computed with JAX (float64 if x64 is on),
    returned as NumPy.

    Args:
        body: the body the file was exported from.
        pose: a `Pose`; its arrays may carry the same leading batch axes, e.g. angles
            (..., n_seg, 3) with position (..., 3).

    Returns:
        array (..., 3 + 3 n_seg): nq of the exported model, MuJoCo's joint order.
    """
    angles = jnp.asarray(pose.angles)
    batch = angles.shape[:-2]
    position = jnp.asarray(pose.position)
    if angles.shape[-2:] != (body.n_segments, 3) or position.shape != batch + (3,):
        raise ValueError(
            f"mujoco_qpos: expected angles (..., {body.n_segments}, 3) and position (..., 3) "
            f"with the same leading axes, got {angles.shape} and {position.shape}"
        )
    flat = jax.tree.map(lambda x: jnp.reshape(x, (-1, *jnp.shape(x)[len(batch) :])), pose)
    position, hinges = _joint_values_batch(body, flat)
    hinges = np.asarray(hinges)[:, np.asarray(_depth_first(body))]
    q = np.concatenate([np.asarray(position), hinges.reshape(len(hinges), -1)], axis=-1)
    return q.reshape(batch + (q.shape[-1],))


# --- shared geometry ------------------------------------------------------------------------
def _f(*values: float | int | np.floating) -> str:
    """Numbers as XML text, each exactly as the float64 it is (shortest round trip)."""
    return " ".join(repr(float(v) + 0.0) for v in values)


def _quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method)."""
    t = np.trace(R)
    k = int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        w = math.sqrt(1.0 + t) / 2.0
        q = [
            w,
            (R[2, 1] - R[1, 2]) / (4 * w),
            (R[0, 2] - R[2, 0]) / (4 * w),
            (R[1, 0] - R[0, 1]) / (4 * w),
        ]
    else:
        i, j, m = k - 1, k % 3, (k + 1) % 3
        v = [0.0, 0.0, 0.0]
        v[i] = math.sqrt(max(1.0 + 2 * R[i, i] - t, 0.0)) / 2.0
        v[j] = (R[j, i] + R[i, j]) / (4 * v[i])
        v[m] = (R[m, i] + R[i, m]) / (4 * v[i])
        q = [(R[m, j] - R[j, m]) / (4 * v[i]), *v]
    q = np.asarray(q)
    return q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF (roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll). yaw = 0 at gimbal lock;
    roll is read off the residual Ry(pitch)^T Rz(yaw)^T R, so it stays exact near it."""
    c = math.hypot(R[0, 0], R[1, 0])
    pitch = math.atan2(-R[2, 0], c)
    yaw = math.atan2(R[1, 0], R[0, 0]) if c > 1e-12 else 0.0
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    # Residual M = Ry(-pitch) Rz(-yaw) R = Rx(roll): roll = atan2(M[2, 1], M[1, 1]).
    m11 = -sy * R[0, 1] + cy * R[1, 1]
    m21 = sp * (cy * R[0, 1] + sy * R[1, 1]) + cp * R[2, 1]
    return math.atan2(m21, m11), pitch, yaw


class _Geometry:
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


def _write(root: ET.Element, path: str | os.PathLike, comment: str) -> Path:
    root.insert(0, ET.Comment(comment))
    tree = ET.ElementTree(root)
    ET.indent(tree, space="  ")
    path = Path(path)
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return path


# --- MJCF -----------------------------------------------------------------------------------
def export_mjcf(body: Body, path: str | os.PathLike) -> Path:
    """Write the body as a MuJoCo MJCF model (DESIGN section 2 as rigid links).

    The file, and what it holds:

    - One `<body>` per segment, named after it, nested as the segment tree. Its frame is the
      segment's *socket* frame placed at the parent's distal joint: pos = (0, 0, L_parent)
      in the parent's twisted frame, quat = R_parent_socket. The whole body hangs from the
      world at the origin (quat = its R_parent_socket).
    - Joints, in `mujoco_qpos` order: the whole body's slides `whole_body_x`, `_y`, `_z`
      along the world axes, then for every segment (whole body included) the hinges
      `{seg}_theta` (axis z), `{seg}_phi` (axis y), `{seg}_twist` (axis z). MuJoCo composes
      them as Rz(theta) Ry(phi) Rz(twist) with twist = s(theta, phi) + tau, so each body's
      `xpos` is the segment's proximal joint and its `xmat` the twisted frame
      `forward(...).R_world_twisted`. Hinges are unlimited: diffbody's limits live in swing
      space, not in (theta, phi); check poses with `diffbody.within_limits`.
    - Surface spheres as `<geom type="sphere">` named `{seg}_sphere_{k}` (k the index in
      `body.sphere_*`), in the twisted frame: they turn with the full twist, where diffbody
      turns them by tau * z / length (partial twist propagation is not representable in a
      rigid body), so they match `forward`'s sphere centres when tau = 0.
    - `<site>`s for the features, named as in `body.feature_names` ("left_hand.palm": MuJoCo
      accepts dots), at origin + radius * direction in the twisted frame (same caveat), and
      for each segment's distal joint, named after the joint ("left_wrist"), at
      (0, 0, length): exact in every pose. Joint 0 ("center_of_gravity", the whole body's
      translating joint) has none: MuJoCo's `subtree_com` gives the center of gravity.
    - `<inertial>` at the centroid with the segment's mass and the isotropic inertia of a
      solid sphere of its enclosure radius (module docstring); massless segments get
      `TINY_MASS`, so the model's total mass exceeds the body's by that.
    - `<contact><exclude>` for segment pairs whose spheres overlap in the standard position
      (neighbouring vertebrae, pelvis and thighs, ...), beyond MuJoCo's own parent-child
      filter, so a simulation does not start in self-contact.
    - A keyframe "standard_position" = `mujoco_qpos(body, body.rest_pose())`; qpos = 0 is
      every segment along its socket's Z, not a human posture.

    Args:
        body: the body (its arrays are written as float64, to the last digit).
        path: the file to write.

    Returns:
        The path written.
    """
    g = _Geometry(body)
    root = ET.Element("mujoco", model=body.name)
    ET.SubElement(root, "compiler", angle="radian")
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "joint", armature=_f(ARMATURE))
    ET.SubElement(default, "geom", type="sphere", rgba=_f(*SPHERE_RGBA))
    ET.SubElement(default, "site", size=_f(SITE_SIZE), rgba=_f(*SITE_RGBA))
    world = ET.SubElement(root, "worldbody")
    elements: list[ET.Element] = []
    for i, name in enumerate(g.names):
        p = g.parent[i]
        up = world if p < 0 else elements[p]
        R = g.R_parent_socket[i]
        el = ET.SubElement(up, "body", name=name, pos=_f(*g.socket_offset(i)), quat=_f(*_quat(R)))
        elements.append(el)
        ET.SubElement(
            el,
            "inertial",
            pos=_f(*g.centroids[i]),
            mass=_f(g.link_masses[i]),
            diaginertia=_f(*[g.inertia[i]] * 3),
        )
        if p < 0:
            # Slide axes in the body frame that are the world axes: rows of R_parent_socket.
            for k, ax in enumerate(SLIDE_AXES):
                ET.SubElement(el, "joint", name=f"{name}_{ax}", type="slide", axis=_f(*R[k]))
        for hinge, axis in zip(HINGES, _HINGE_AXES):
            ET.SubElement(el, "joint", name=f"{name}_{hinge}", type="hinge", axis=_f(*axis))
        for k, origin, radius in g.spheres[i]:
            ET.SubElement(el, "geom", name=f"{name}_sphere_{k}", pos=_f(*origin), size=_f(radius))
        for feature, point in g.features[i]:
            ET.SubElement(el, "site", name=feature, pos=_f(*point))
        ET.SubElement(el, "site", name=g.distal_joint_names[i], pos=_f(0.0, 0.0, g.lengths[i]))
    contact = ET.SubElement(root, "contact")
    for a, b in g.overlapping_pairs():
        ET.SubElement(contact, "exclude", body1=g.names[a], body2=g.names[b])
    keyframe = ET.SubElement(root, "keyframe")
    ET.SubElement(
        keyframe, "key", name="standard_position", qpos=_f(*mujoco_qpos(body, body.rest_pose()))
    )
    return _write(
        root,
        path,
        f" {body.name} ({Path(body.source).name}), exported by diffbody. Each body is a "
        "segment's socket frame; hinges theta (z), phi (y), twist (z) give "
        "Rz(theta) Ry(phi) Rz(s + tau). Spheres and sites are in the twisted frame: they "
        "turn with the full twist. Set qpos with diffbody's mujoco_qpos. ",
    )


# --- URDF -----------------------------------------------------------------------------------
def _chain_segments(body: Body, chain: Sequence[str] | None) -> list[int]:
    """Segment indices exported: all, or the path from chain[0] down to chain[1]."""
    if chain is None:
        return list(range(body.n_segments))
    if isinstance(chain, str) or len(chain) != 2:
        raise ValueError(f"chain: expected (first segment, last segment), got {chain!r}")
    first, last = (body.segment_index(name) for name in chain)
    path = [last]
    while path[-1] != first:
        p = body.parent[path[-1]]
        if p < 0:
            raise ValueError(
                f"chain: segment {chain[1]!r} is not below {chain[0]!r}; the chain runs from a "
                f"segment down to one of its descendants (the path from {chain[1]!r} up to the "
                f"world is {' <- '.join(body.segment_names[k] for k in path)} <- world)"
            )
        path.append(p)
    return path[::-1]


def _urdf_inertial(link: ET.Element, xyz, mass: float, inertia: float) -> None:
    el = ET.SubElement(link, "inertial")
    ET.SubElement(el, "origin", xyz=_f(*xyz), rpy="0 0 0")
    ET.SubElement(el, "mass", value=_f(mass))
    ET.SubElement(
        el, "inertia", ixx=_f(inertia), iyy=_f(inertia), izz=_f(inertia), ixy="0", ixz="0", iyz="0"
    )


def _urdf_joint(
    robot: ET.Element, name: str, kind: str, parent: str, child: str, xyz, rpy, axis=None
) -> None:
    el = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(el, "parent", link=parent)
    ET.SubElement(el, "child", link=child)
    ET.SubElement(el, "origin", xyz=_f(*xyz), rpy=_f(*rpy))
    if axis is not None:
        ET.SubElement(el, "axis", xyz=_f(*axis))
        lo, hi = URDF_LIMITS[name.rsplit("_", 1)[1]]
        ET.SubElement(
            el,
            "limit",
            lower=_f(lo),
            upper=_f(hi),
            effort=_f(URDF_EFFORT),
            velocity=_f(URDF_VELOCITY),
        )


def export_urdf(
    body: Body,
    path: str | os.PathLike,
    *,
    chain: Sequence[str] | None = None,
    name: str | None = None,
) -> Path:
    """Write the body, or one chain of it, as a URDF robot.

    URDF joints have one degree of freedom, so segment `{seg}` becomes three links,
    `{seg}_theta_link`, `{seg}_phi_link` and `{seg}`, joined by revolute joints `{seg}_theta`
    (axis z), `{seg}_phi` (axis y) and `{seg}_twist` (axis z) with values theta, phi and
    s(theta, phi) + tau (`urdf_joint_values`). `{seg}_theta`'s origin is the socket
    placement: xyz = (0, 0, L_parent) and rpy from R_parent_socket, in the parent's link
    frame; the other two have identity origins. Link `{seg}` is the segment's twisted frame
    (`forward(...).R_world_twisted`, origin at the proximal joint); it carries the surface
    spheres (visual and collision, in the twisted frame: they turn with the full twist, see
    the module docstring) and the inertial of `export_mjcf`. The intermediate links carry
    `TINY_MASS`. URDF has no sites: feature points are not exported.

    Limits (URDF requires them on revolute joints): theta [-pi, pi], phi [0, pi], twist
    [-2 pi, 2 pi]. They only keep the angles in range: the true limits are in swing space
    (`diffbody.within_limits`). Effort and velocity limits are placeholders
    (`URDF_EFFORT`, `URDF_VELOCITY`).

    Placement. URDF has no free joint. The whole tree (`chain=None`) hangs from a link
    `world`; the whole body is fixed to it by joint `whole_body_fixed` at its
    standard-position placement (origin at `body.rest_position` for the default root, the
    standard position's orientation): so link frames equal `forward`'s for poses whose
    position is the rest position and whose whole-body row is the rest pose's. For other
    stances, move the URDF's world frame yourself.

    `chain=(first, last)` exports only the path from segment `first` down to segment
    `last`. `first`'s parent becomes a fixed link `base`: the parent's own link frame
    (its twisted frame at its proximal joint), so every joint of the chain, the first
    included, has the same origin as in the whole-tree file, and link frames equal
    `forward`'s expressed in the parent's twisted frame. A chain that starts at the whole
    body hangs from `base` as the whole tree hangs from `world`.

    Args:
        body: the body.
        path: the file to write.
        chain: None, or (first segment name, last segment name).
        name: the robot's name; the body's name by default.

    Returns:
        The path written.

    Raises:
        KeyError: an unknown segment name in `chain` (the message lists the valid names).
        ValueError: `last` is not `first` or below it.
    """
    segments = _chain_segments(body, chain)
    g = _Geometry(body)
    robot = ET.Element("robot", name=name or body.name)
    ET.SubElement(ET.SubElement(robot, "material", name="skin"), "color", rgba=_f(*SPHERE_RGBA))
    base = "world" if chain is None else "base"
    ET.SubElement(robot, "link", name=base)
    for i in segments:
        seg = g.names[i]
        if g.parent[i] < 0:
            R0 = g.R_rest_whole
            _urdf_joint(robot, f"{seg}_fixed", "fixed", base, seg, g.rest_origin, _rpy(R0))
        else:
            up = base if i == segments[0] else g.names[g.parent[i]]
            links = (f"{seg}_theta_link", f"{seg}_phi_link", seg)
            origins = ((g.socket_offset(i), _rpy(g.R_parent_socket[i])), ((0, 0, 0), (0, 0, 0)))
            origins += (((0, 0, 0), (0, 0, 0)),)
            for hinge, axis, link, (xyz, rpy) in zip(HINGES, _HINGE_AXES, links, origins):
                _urdf_joint(robot, f"{seg}_{hinge}", "revolute", up, link, xyz, rpy, axis)
                if link != seg:
                    _urdf_inertial(
                        ET.SubElement(robot, "link", name=link), (0, 0, 0), TINY_MASS, TINY_INERTIA
                    )
                up = link
        link = ET.SubElement(robot, "link", name=seg)
        _urdf_inertial(link, g.centroids[i], g.link_masses[i], g.inertia[i])
        for k, origin, radius in g.spheres[i]:
            for kind in ("visual", "collision"):
                el = ET.SubElement(link, kind, name=f"{seg}_sphere_{k}")
                ET.SubElement(el, "origin", xyz=_f(*origin), rpy="0 0 0")
                ET.SubElement(ET.SubElement(el, "geometry"), "sphere", radius=_f(radius))
                if kind == "visual":
                    ET.SubElement(el, "material", name="skin")
    what = "the whole body" if chain is None else f"the chain {chain[0]} .. {chain[1]}"
    return _write(
        robot,
        path,
        f" {body.name} ({Path(body.source).name}): {what}, exported by diffbody. Joints "
        "{seg}_theta (z), _phi (y), _twist (z) give Rz(theta) Ry(phi) Rz(s + tau); set "
        "them with diffbody's urdf_joint_values. Link {seg} is the twisted frame; spheres "
        "turn with the full twist. ",
    )


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles into [-pi, pi] (modulo a full turn), unchanged where already inside."""
    return np.where(np.abs(a) <= np.pi, a, a - 2 * np.pi * np.round(a / (2 * np.pi)))


def urdf_joint_values(
    body: Body, pose: Pose, chain: Sequence[str] | None = None
) -> dict[str, float]:
    """Joint values of a pose for `export_urdf`'s file with the same `chain`.

    theta is wrapped into [-pi, pi], and s(theta, phi) + tau, when outside [-2 pi, 2 pi]
    (the left arm's table reaches about 3 pi beside its seam), into [-pi, pi]: the same
    rotations, within the file's limits. phi is passed as is (in [0, pi] for every pose
    diffbody makes). For a pose with a spine target, the segments the spine moves get the ZYZ
    angles of their frames in `forward`, as in `mujoco_qpos`.

    Returns:
        {"{seg}_theta": theta, "{seg}_phi": phi, "{seg}_twist": s(theta, phi) + tau} (rad) for
        every exported segment but the whole body (fixed in the file; `pose.position` and
        the whole-body row are not used).
    """
    segments = _chain_segments(body, chain)
    shape = jnp.shape(pose.angles)
    if shape != (body.n_segments, 3):
        raise ValueError(f"urdf_joint_values: expected angles ({body.n_segments}, 3), got {shape}")
    _, hinges = _joint_values_batch(body, jax.tree.map(lambda x: jnp.asarray(x)[None], pose))
    values = np.array(hinges[0], dtype=np.float64)
    values[:, 0] = _wrap(values[:, 0])
    twist = values[:, 2]
    values[:, 2] = np.where(np.abs(twist) > 2 * np.pi, _wrap(twist), twist)
    return {
        f"{body.segment_names[i]}_{hinge}": float(values[i, k])
        for i in segments
        if body.parent[i] >= 0
        for k, hinge in enumerate(HINGES)
    }
