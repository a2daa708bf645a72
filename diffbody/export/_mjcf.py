"""MuJoCo MJCF export: a body as an MJCF model (`export_mjcf`) and a pose as its qpos
(`mujoco_qpos`, `mujoco_joint_names`). The rigid-link conventions, and what they cannot say
of a diffbody body, are in `_rigid_links`.
"""

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._body import Body, Pose
from ._rigid_links import (
    HINGE_AXES,
    HINGES,
    SPHERE_RGBA,
    Geometry,
    joint_values_batch,
    write_xml,
    xml_numbers,
)

SLIDE_AXES = ("x", "y", "z")  # MJCF: whole_body_x, whole_body_y, whole_body_z
ARMATURE = 1e-3  # kg m^2, MJCF joints: keeps MuJoCo's mass matrix regular at the poles
SITE_RGBA = (0.8, 0.1, 0.1, 1.0)
SITE_SIZE = 0.005  # m


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
    position, hinges = joint_values_batch(body, flat)
    hinges = np.asarray(hinges)[:, np.asarray(_depth_first(body))]
    q = np.concatenate([np.asarray(position), hinges.reshape(len(hinges), -1)], axis=-1)
    return q.reshape(batch + (q.shape[-1],))


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


def export_mjcf(
    body: Body, path: str | os.PathLike, exclude: Iterable[tuple[str, str]] | None = None
) -> Path:
    """Write the body as a MuJoCo MJCF model (docs/design.md, section 2 as rigid links:
    `_rigid_links`, whose hinges and caveats apply).

    The file, and what it holds:

    - One `<body>` per segment, named after it, nested as the segment tree, at the segment's
      *socket* frame: pos = (0, 0, L_parent) in the parent's twisted frame, quat =
      R_parent_socket (the whole body hangs from the world at the origin).
    - Joints, in `mujoco_qpos` order: the whole body's slides `whole_body_x`, `_y`, `_z`
      along the world axes, then every segment's hinges `{seg}_theta` (z), `{seg}_phi` (y),
      `{seg}_twist` (z), unlimited: each body's `xpos` is the segment's proximal joint and
      its `xmat` `forward(...).R_world_twisted`.
    - Surface spheres as `<geom type="sphere">` named `{seg}_sphere_{k}` (k the index in
      `body.sphere_*`) and `<site>`s for the features (`body.feature_names`), in the twisted
      frame; a `<site>` at each segment's distal joint, named after it ("left_wrist"), exact
      in every pose (the center of gravity has none: MuJoCo's `subtree_com` gives it).
    - `<inertial>` at the centroid with the segment's mass (`TINY_MASS` when massless, so the
      model's total mass exceeds the body's by that).
    - `<contact><exclude>` for segment pairs whose spheres overlap in the standard position,
      beyond MuJoCo's parent-child filter, so a simulation does not start in self-contact;
      or, when `exclude` is given, for exactly those segment pairs (MuJoCo's parent-child
      filter still applies).
    - A keyframe "standard_position" = `mujoco_qpos(body, body.rest_pose())`; qpos = 0 is
      every segment along its socket's Z, not a human posture.

    Args:
        body: the body (its arrays are written as float64, to the last digit).
        path: the file to write.
        exclude: segment name pairs whose spheres MuJoCo must not collide, instead of the
            default (the pairs overlapping in the standard position); e.g. the pairs that
            `diffbody.contact` never checks, so that MuJoCo collides the pairs it checks (they
            include every parent and child: MuJoCo's parent filter drops no other pair).

    Returns:
        The path written.
    """
    g = Geometry(body)
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
        el = ET.SubElement(
            up, "body", name=name, pos=xml_numbers(*g.socket_offset(i)), quat=xml_numbers(*_quat(R))
        )
        elements.append(el)
        ET.SubElement(
            el,
            "inertial",
            pos=xml_numbers(*g.centroids[i]),
            mass=xml_numbers(g.link_masses[i]),
            diaginertia=xml_numbers(*[g.inertia[i]] * 3),
        )
        if p < 0:
            # Slide axes in the body frame that are the world axes: rows of R_parent_socket.
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
    ET.SubElement(
        keyframe,
        "key",
        name="standard_position",
        qpos=xml_numbers(*mujoco_qpos(body, body.rest_pose())),
    )
    return write_xml(
        root,
        path,
        f" {body.name} ({Path(body.source).name}), exported by diffbody. Each body is a "
        "segment's socket frame; hinges theta (z), phi (y), twist (z) give "
        "Rz(theta) Ry(phi) Rz(s + tau). Spheres and sites are in the twisted frame: they "
        "turn with the full twist. Set qpos with diffbody's mujoco_qpos. ",
    )
