"""MuJoCo MJCF export: a body as an MJCF model (`export_mjcf`) and a pose as its qpos
(`mujoco_qpos`, `mujoco_joint_names`, `mujoco_qpos_slices`). The rigid-link conventions, and
what they cannot say of a diffbody body, are in `_rigid_links`; the ball joints' ranges come
from `_limit_sets`.
"""

import os
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .._body import Body, Pose
from ._limit_sets import ball_ranges
from ._rigid_links import (
    HINGE_AXES,
    HINGES,
    SPHERE_RGBA,
    Geometry,
    batch_poses,
    joint_values_batch,
    quat_wxyz,
    rest_relative_rotations,
    socket_rotations_batch,
    write_xml,
    xml_numbers,
)

JOINTS = ("ball", "hinges")  # export_mjcf's joint models
SLIDE_AXES = ("x", "y", "z")  # hinge model: whole_body_x, whole_body_y, whole_body_z
ARMATURE = 1e-3  # kg m^2, MJCF joints: keeps MuJoCo's mass matrix regular at the poles
SITE_RGBA = (0.8, 0.1, 0.1, 1.0)
SITE_SIZE = 0.005  # m


class SingularJointsWarning(UserWarning):
    """The ZYZ hinge model is singular in the standard position (phi = 0 or pi)."""


def _check_joints(name: str, joints: str) -> None:
    if joints not in JOINTS:
        raise ValueError(f"{name}: joints must be one of {JOINTS}, got {joints!r}")


def _depth_first(body: Body) -> list[int]:
    """Segments in depth-first pre-order, children in index order: the order of the nested
    MJCF bodies, hence of MuJoCo's joints and qpos."""
    order, stack = [], [0]
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(k for k in reversed(range(body.n_segments)) if body.parent[k] == i)
    return order


def _joint_sizes(body: Body, joints: str) -> list[tuple[str, int]]:
    """(joint name, qpos entries) in MuJoCo's order for the joint model `joints`."""
    seg = body.segment_names
    if joints == "hinges":
        out = [(f"{seg[0]}_{ax}", 1) for ax in SLIDE_AXES]
        return out + [(f"{seg[i]}_{h}", 1) for i in _depth_first(body) for h in HINGES]
    return [(f"{seg[0]}_free", 7)] + [(f"{seg[i]}_ball", 4) for i in _depth_first(body)[1:]]


def mujoco_joint_names(body: Body, joints: str = "ball") -> tuple[str, ...]:
    """Names of the joints of `export_mjcf`'s file, in MuJoCo's order (the nesting of the
    file's bodies: segments depth first, starting with whole_body).

    joints="ball": `whole_body_free` (7 qpos entries), then `{seg}_ball` (4 each).
    joints="hinges": `whole_body_x`, `_y`, `_z`, then `{seg}_theta`, `{seg}_phi`,
    `{seg}_twist` for every segment, whole_body first (1 each). `mujoco_qpos_slices` gives
    each joint's entries of qpos."""
    _check_joints("mujoco_joint_names", joints)
    return tuple(name for name, _ in _joint_sizes(body, joints))


def mujoco_qpos_slices(body: Body, joints: str = "ball") -> dict[str, slice]:
    """{joint name: its slice of qpos} for `export_mjcf`'s file, in MuJoCo's joint order
    (MuJoCo's `model.jnt_qposadr`): a ball takes 4 entries (w, x, y, z), the free joint 7
    (x, y, z, then w, x, y, z), a hinge or slide 1."""
    _check_joints("mujoco_qpos_slices", joints)
    out, start = {}, 0
    for name, size in _joint_sizes(body, joints):
        out[name] = slice(start, start + size)
        start += size
    return out


def mujoco_qpos(body: Body, pose: Pose, joints: str = "ball") -> np.ndarray:
    """MuJoCo `qpos` of a pose, in the joint order of `export_mjcf`'s file (same `joints`).

    joints="ball": the whole body's proximal joint (x, y, z, m) and its twisted frame in the
    world as a quaternion (w, x, y, z), then per segment (depth first,
    `mujoco_joint_names`) the quaternion of Q = R_rest^T R_socket_twisted, its rotation
    from the standard position (R_rest = `body.R_socket_rest`): the identity quaternion at
    rest, and no gimbal lock anywhere. Quaternions have w >= 0.

    joints="hinges": (x, y, z of the whole body's proximal joint, then for every segment:
    theta, phi, s(theta, phi) + tau), s the standard twist, so that MuJoCo's Rz(theta)
    Ry(phi) Rz(twist) is diffbody's segment frame; angles as given, not wrapped (the hinges
    are unlimited). Rows the pose sets keep its theta and phi.

    Both: for a body with its default root the position is `pose.position`; for a re-rooted
    body (`Body.with_root`) the whole body's position and frame are its proximal joint and
    twisted frame in `forward`. For a pose with a spine target, the segments the spine
    moves take their frames in `forward` (their pose rows are not used). Computed with JAX
    (float64 if x64 is on), returned as NumPy.

    Args:
        body: the body the file was exported from.
        pose: a `Pose`; its arrays may carry the same leading batch axes, e.g. angles
            (..., n_seg, 3) with position (..., 3).
        joints: "ball" or "hinges", as given to `export_mjcf`.

    Returns:
        array (..., nq): nq = 7 + 4 (n_seg - 1) for balls, 3 + 3 n_seg for hinges.
    """
    _check_joints("mujoco_qpos", joints)
    batch, flat = batch_poses("mujoco_qpos", body, pose)
    order = np.asarray(_depth_first(body))
    if joints == "hinges":
        position, hinges = joint_values_batch(body, flat)
        hinges = np.asarray(hinges)[:, order]
        q = np.concatenate([np.asarray(position), hinges.reshape(len(hinges), -1)], axis=-1)
    else:
        position, R_world_whole, R_socket_twisted = socket_rotations_batch(body, flat)
        Q = rest_relative_rotations(body, np.asarray(R_socket_twisted))[:, order[1:]]
        balls = quat_wxyz(Q).reshape(len(Q), -1)
        whole = quat_wxyz(np.asarray(R_world_whole))
        q = np.concatenate([np.asarray(position), whole, balls], axis=-1)
    return q.reshape(batch + (q.shape[-1],))


def _excluded_pairs(body: Body, exclude: Iterable[tuple[str, str]]) -> list[tuple[int, int]]:
    """Segment index pairs (a < b), sorted, of `export_mjcf`'s `exclude` (checked)."""
    out = set()
    for item in exclude:
        names = tuple(item) if not isinstance(item, str) else (item,)
        if len(names) != 2 or not all(isinstance(n, str) for n in names):
            raise ValueError(f"export_mjcf: exclude takes pairs of segment names, got {item!r}")
        a, b = (body.segment_index(n) for n in names)
        if a == b:
            raise ValueError(f"export_mjcf: exclude pairs two different segments, got {item!r}")
        out.add((min(a, b), max(a, b)))
    return sorted(out)


def _keyframes(body: Body, pose: Pose | None, joints: str) -> list[tuple[str, np.ndarray]]:
    """(name, qpos) of the file's keyframes: the pose ("pose", or "pose_{k}" per row of a
    pose with one leading axis) first, then "standard_position"."""
    keys = []
    if pose is not None:
        q = mujoco_qpos(body, pose, joints)
        if q.ndim == 1:
            keys.append(("pose", q))
        elif q.ndim == 2:
            keys += [(f"pose_{k}", row) for k, row in enumerate(q)]
        else:
            raise ValueError(f"export_mjcf: pose has {q.ndim - 1} leading axes; at most one")
    return keys + [("standard_position", mujoco_qpos(body, body.rest_pose(), joints))]


def export_mjcf(
    body: Body,
    path: str | os.PathLike,
    exclude: Iterable[tuple[str, str]] | None = None,
    *,
    joints: str = "ball",
    pose: Pose | None = None,
) -> Path:
    """Write the body as a MuJoCo MJCF model (docs/design.md, section 2 as rigid links:
    `_rigid_links`, whose caveats apply).

    The file, and what it holds:

    - One `<body>` per segment, named after it, nested as the segment tree, hanging from
      its parent's twisted frame at (0, 0, L_parent). Each body's `xpos` is the segment's
      proximal joint and its `xmat` `forward(...).R_world_twisted`.
    - joints="ball" (the default): the whole body has a free joint `whole_body_free` and
      every other segment a ball `{seg}_ball`, its zero the segment's standard-position
      frame (the body's quat is R_parent_socket R_socket_rest), so qpos0 is the standard
      position and no pose is a gimbal lock. Each ball is limited to the largest rotation
      from rest its limits allow (`_limit_sets.ball_ranges`: the limit set sampled, radians,
      an outer bound; unlimited for "free" limits). The exact shape of the limits (a box and
      a cone of swing vectors, a twist range) is more than MuJoCo can state: check poses
      with `within_limits`.
    - joints="hinges" (warns: `SingularJointsWarning`): the former model, three slides
      `whole_body_x`, `_y`, `_z` along the world axes, then every segment's hinges
      `{seg}_theta` (z), `{seg}_phi` (y), `{seg}_twist` (z), unlimited, each body at its
      socket frame. theta and twist share an axis where phi = 0 or pi: every hanging limb
      and the spine in the standard position.
    - Surface spheres as `<geom type="sphere">` named `{seg}_sphere_{k}` (k the index in
      `body.sphere_*`) and `<site>`s for the features (`body.feature_names`), in the twisted
      frame; a `<site>` at each segment's distal joint, named after it ("left_wrist"), exact
      in every pose (the center of gravity has none: MuJoCo's `subtree_com` gives it).
    - `<inertial>` at the centroid with the segment's mass and `fullinertia` the tensor of
      its spheres (`_rigid_links.sphere_inertia`; `TINY_MASS` and `TINY_INERTIA` when
      massless, so the model's total mass exceeds the body's by that).
    - `<contact><exclude>` for segment pairs whose spheres overlap in the standard position,
      beyond MuJoCo's parent-child filter, so a simulation does not start in self-contact;
      or, when `exclude` is given, for exactly those segment pairs (MuJoCo's parent-child
      filter still applies).
    - Keyframes: `pose`, when given, first (key 0, `mj_resetDataKeyframe(model, data, 0)`),
      then "standard_position" = `mujoco_qpos(body, body.rest_pose(), joints)`.

    Args:
        body: the body (its arrays are written as float64, to the last digit).
        path: the file to write.
        exclude: segment name pairs whose spheres MuJoCo must not collide, instead of the
            default (the pairs overlapping in the standard position); e.g. the pairs that
            `diffbody.contact` never checks, so that MuJoCo collides the pairs it checks (they
            include every parent and child: MuJoCo's parent filter drops no other pair).
        joints: "ball" or "hinges".
        pose: an initial configuration, written as keyframe "pose"; with one leading axis
            (a sequence), one keyframe "pose_{k}" per row.

    Returns:
        The path written.
    """
    _check_joints("export_mjcf", joints)
    balls = joints == "ball"
    if not balls:
        warnings.warn(
            "export_mjcf(joints='hinges'): the ZYZ hinges theta, phi, twist are singular at "
            "phi = 0 or pi, where hanging limbs and the spine rest in the standard position "
            "(theta and twist turn about one axis there); joints='ball' has no singularity",
            SingularJointsWarning,
            stacklevel=2,
        )
    g = Geometry(body)
    ranges = ball_ranges(body) if balls else None
    keys = _keyframes(body, pose, joints)
    R_rest = np.asarray(body.R_socket_rest, np.float64)
    root = ET.Element("mujoco", model=body.name)
    ET.SubElement(root, "compiler", angle="radian")
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "joint", armature=xml_numbers(ARMATURE))
    ET.SubElement(default, "geom", type="sphere", rgba=xml_numbers(*SPHERE_RGBA))
    ET.SubElement(default, "site", size=xml_numbers(SITE_SIZE), rgba=xml_numbers(*SITE_RGBA))
    world = ET.SubElement(root, "worldbody")
    elements: list[ET.Element] = []
    for i, name in enumerate(g.names):
        p = g.parent[i]
        up = world if p < 0 else elements[p]
        R = g.R_parent_socket[i]
        # The body frame at qpos0: the socket (hinges: their zero is the socket's axes) or
        # the standard position (balls and the free joint: their zero is rest).
        pos, R_up_body = g.socket_offset(i), R @ R_rest[i] if balls else R
        if balls and p < 0:
            pos = g.rest_origin
        el = ET.SubElement(
            up, "body", name=name, pos=xml_numbers(*pos), quat=xml_numbers(*quat_wxyz(R_up_body))
        )
        elements.append(el)
        inertia = g.inertia[i]
        ET.SubElement(
            el,
            "inertial",
            pos=xml_numbers(*g.centroids[i]),
            mass=xml_numbers(g.link_masses[i]),
            fullinertia=xml_numbers(*inertia[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]),
        )
        if balls and p < 0:
            ET.SubElement(el, "joint", name=f"{name}_free", type="free")
        elif balls:
            limit = {"limited": "false"}
            if np.isfinite(ranges[i]):
                limit = {"limited": "true", "range": xml_numbers(0.0, ranges[i])}
            ET.SubElement(el, "joint", name=f"{name}_ball", type="ball", **limit)
        else:
            if p < 0:
                # Slide axes in the body frame that are the world axes: rows of
                # R_parent_socket.
                for k, ax in enumerate(SLIDE_AXES):
                    ET.SubElement(
                        el, "joint", name=f"{name}_{ax}", type="slide", axis=xml_numbers(*R[k])
                    )
            for hinge, axis in zip(HINGES, HINGE_AXES):
                ET.SubElement(
                    el, "joint", name=f"{name}_{hinge}", type="hinge", axis=xml_numbers(*axis)
                )
        for k, origin, radius in g.spheres[i]:
            ET.SubElement(
                el,
                "geom",
                name=f"{name}_sphere_{k}",
                pos=xml_numbers(*origin),
                size=xml_numbers(radius),
            )
        for feature, point in g.features[i]:
            ET.SubElement(el, "site", name=feature, pos=xml_numbers(*point))
        ET.SubElement(
            el, "site", name=g.distal_joint_names[i], pos=xml_numbers(0.0, 0.0, g.lengths[i])
        )
    contact = ET.SubElement(root, "contact")
    pairs = g.overlapping_pairs() if exclude is None else _excluded_pairs(body, exclude)
    for a, b in pairs:
        ET.SubElement(contact, "exclude", body1=g.names[a], body2=g.names[b])
    keyframe = ET.SubElement(root, "keyframe")
    for key, qpos in keys:
        ET.SubElement(keyframe, "key", name=key, qpos=xml_numbers(*qpos))
    what = (
        "a free joint, then per segment a ball about its standard-position frame, limited to "
        "the largest rotation its limits allow (check poses with diffbody's within_limits)"
        if balls
        else "hinges theta (z), phi (y), twist (z) give Rz(theta) Ry(phi) Rz(s + tau), "
        "singular at phi = 0 and pi"
    )
    return write_xml(
        root,
        path,
        f" {body.name} ({Path(body.source).name}), exported by diffbody. Each body is a "
        f"segment's twisted frame; joints: {what}. Spheres and sites turn with the full "
        "twist. Set qpos with diffbody's mujoco_qpos. ",
    )
