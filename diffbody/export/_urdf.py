"""URDF export: a body, or one chain of it, as a URDF robot (`export_urdf`) and a pose as
its joint values (`urdf_joint_values`). The rigid-link conventions, and what they cannot say
of a diffbody body, are in `_rigid_links`.
"""

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._body import Body, Pose
from ._rigid_links import (
    HINGE_AXES,
    HINGES,
    SPHERE_RGBA,
    TINY_INERTIA,
    TINY_MASS,
    Geometry,
    joint_values_batch,
    write_xml,
    xml_numbers,
)

URDF_LIMITS = {
    "theta": (-math.pi, math.pi),
    "phi": (0.0, math.pi),
    "twist": (-2 * math.pi, 2 * math.pi),
}
URDF_EFFORT = 1000.0  # N m, placeholder: URDF requires one; diffbody has no actuators
URDF_VELOCITY = 50.0  # rad/s, placeholder


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
    ET.SubElement(el, "origin", xyz=xml_numbers(*xyz), rpy="0 0 0")
    ET.SubElement(el, "mass", value=xml_numbers(mass))
    ET.SubElement(
        el,
        "inertia",
        ixx=xml_numbers(inertia),
        iyy=xml_numbers(inertia),
        izz=xml_numbers(inertia),
        ixy="0",
        ixz="0",
        iyz="0",
    )


def _urdf_joint(
    robot: ET.Element, name: str, kind: str, parent: str, child: str, xyz, rpy, axis=None
) -> None:
    el = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(el, "parent", link=parent)
    ET.SubElement(el, "child", link=child)
    ET.SubElement(el, "origin", xyz=xml_numbers(*xyz), rpy=xml_numbers(*rpy))
    if axis is not None:
        ET.SubElement(el, "axis", xyz=xml_numbers(*axis))
        lo, hi = URDF_LIMITS[name.rsplit("_", 1)[1]]
        ET.SubElement(
            el,
            "limit",
            lower=xml_numbers(lo),
            upper=xml_numbers(hi),
            effort=xml_numbers(URDF_EFFORT),
            velocity=xml_numbers(URDF_VELOCITY),
        )


def export_urdf(
    body: Body,
    path: str | os.PathLike,
    *,
    chain: Sequence[str] | None = None,
    name: str | None = None,
) -> Path:
    """Write the body, or one chain of it, as a URDF robot (rigid links: `_rigid_links`).

    URDF joints have one degree of freedom, so segment `{seg}` becomes three links,
    `{seg}_theta_link`, `{seg}_phi_link` and `{seg}`, joined by the revolute joints
    `{seg}_theta` (z), `{seg}_phi` (y) and `{seg}_twist` (z) (`urdf_joint_values`).
    `{seg}_theta`'s origin is the socket placement, (0, 0, L_parent) and R_parent_socket in
    the parent's link frame; the other two have identity origins. Link `{seg}` is the
    segment's twisted frame and carries the surface spheres (visual and collision) and the
    inertial of `export_mjcf`; the intermediate links carry `TINY_MASS`. Feature points are
    not exported (URDF has no sites). Limits keep the angles in range only: theta [-pi, pi],
    phi [0, pi], twist [-2 pi, 2 pi]; effort and velocity are placeholders (`URDF_EFFORT`,
    `URDF_VELOCITY`).

    Placement. URDF has no free joint. The whole tree (`chain=None`) hangs from a link
    `world`; the whole body is fixed to it by joint `whole_body_fixed` at its
    standard-position placement (origin at `body.rest_position` for the default root, the
    standard position's orientation): so link frames equal `forward`'s for poses whose
    position is the rest position and whose whole-body row is the rest pose's. For other
    stances, move the URDF's world frame yourself.

    `chain=(first, last)` exports only the path from segment `first` down to segment
    `last`, hanging from a fixed link `base`: `first`'s parent's link frame (its twisted
    frame at its proximal joint), so every joint keeps its whole-tree origin and link frames
    equal `forward`'s in the parent's twisted frame. A chain that starts at the whole body
    hangs from `base` as the whole tree hangs from `world`.

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
    g = Geometry(body)
    robot = ET.Element("robot", name=name or body.name)
    ET.SubElement(
        ET.SubElement(robot, "material", name="skin"), "color", rgba=xml_numbers(*SPHERE_RGBA)
    )
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
            for hinge, axis, link, (xyz, rpy) in zip(HINGES, HINGE_AXES, links, origins):
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
                ET.SubElement(el, "origin", xyz=xml_numbers(*origin), rpy="0 0 0")
                ET.SubElement(ET.SubElement(el, "geometry"), "sphere", radius=xml_numbers(radius))
                if kind == "visual":
                    ET.SubElement(el, "material", name="skin")
    what = "the whole body" if chain is None else f"the chain {chain[0]} .. {chain[1]}"
    return write_xml(
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
    _, hinges = joint_values_batch(body, jax.tree.map(lambda x: jnp.asarray(x)[None], pose))
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
