"""URDF export: a body, or one chain of it, as a URDF robot (`export_urdf`) and a pose as
its joint values (`urdf_joint_values`). The rigid-link conventions, and what they cannot say
of a diffbody body, are in `_rigid_links`; the hinges' axes and bounds come from
`_limit_sets`.
"""

import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._body import Body, Pose
from ._limit_sets import euler_hinges, hinge_values
from ._rigid_links import (
    SPHERE_RGBA,
    TINY_INERTIA,
    TINY_MASS,
    Geometry,
    rest_relative_rotations,
    rpy,
    socket_rotations_batch,
    write_xml,
    xml_numbers,
)

N_HINGES = 3  # joints {seg}_hinge0, _hinge1, _hinge2 per segment
URDF_EFFORT = 1000.0  # N m, placeholder: URDF requires one; diffbody has no actuators
URDF_VELOCITY = 50.0  # rad/s, placeholder


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


def _urdf_inertial(link: ET.Element, xyz, mass: float, inertia: np.ndarray) -> None:
    """An `<inertial>` at xyz with mass (kg) and inertia tensor (3, 3) (kg m^2)."""
    el = ET.SubElement(link, "inertial")
    ET.SubElement(el, "origin", xyz=xml_numbers(*xyz), rpy="0 0 0")
    ET.SubElement(el, "mass", value=xml_numbers(mass))
    names = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
    entries = inertia[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
    ET.SubElement(el, "inertia", **{k: xml_numbers(v) for k, v in zip(names, entries)})


def _urdf_joint(
    robot: ET.Element,
    name: str,
    kind: str,
    parent: str,
    child: str,
    xyz,
    angles,
    axis=None,
    bounds=(0.0, 0.0),
) -> None:
    el = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(el, "parent", link=parent)
    ET.SubElement(el, "child", link=child)
    ET.SubElement(el, "origin", xyz=xml_numbers(*xyz), rpy=xml_numbers(*angles))
    if axis is not None:
        ET.SubElement(el, "axis", xyz=xml_numbers(*axis))
        lo, hi = bounds
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
    `{seg}_hinge0_link`, `{seg}_hinge1_link` and `{seg}`, joined by the revolute joints
    `{seg}_hinge0`, `_hinge1`, `_hinge2`, whose values are Euler angles of the segment's
    rotation from its standard-position frame (`urdf_joint_values`): zero in the standard
    position. Their axes are chosen per segment from its limits so that the middle hinge's
    singularity (+-90 deg, where the first and last axes align) lies outside them
    (`_limit_sets.euler_hinges`: the rest frame's own axes in the order that keeps farthest
    from it, e.g. y, x, z for the thigh; for a shoulder, which reaches every axis, the
    farthest of many tilted frames). Each hinge's limits are the bounding box of the limit
    set in those angles (sampled, an outer bound); the exact set is more than URDF can
    state: check poses with `within_limits`. Effort and velocity are placeholders
    (`URDF_EFFORT`, `URDF_VELOCITY`).

    `{seg}_hinge0`'s origin is the socket placement, (0, 0, L_parent) and
    R_parent_socket R_socket_rest (the standard-position frame) in the parent's link frame;
    the other two have identity origins. Link `{seg}` is the segment's twisted frame and
    carries the surface spheres (visual and collision) and the inertial of `export_mjcf`
    (the spheres' inertia tensor at the centroid); the intermediate links carry
    `TINY_MASS`. Feature points are not exported (URDF has no sites).

    Placement. URDF has no free joint. The whole tree (`chain=None`) hangs from a link
    `world`; the whole body is fixed to it by joint `whole_body_fixed` at its
    standard-position placement (origin at `body.rest_position` for the default root, the
    standard position's orientation): so link frames equal `forward`'s for poses whose
    position is the rest position and whose whole-body row is the rest pose's. For other
    stances, move the URDF's world frame yourself. URDF has no initial state either: set
    the joints to `urdf_joint_values` of a pose (the `diffbody export` command writes them
    beside the file).

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
    hinges = euler_hinges(body)
    R_rest = np.asarray(body.R_socket_rest, np.float64)
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
            _urdf_joint(robot, f"{seg}_fixed", "fixed", base, seg, g.rest_origin, rpy(R0))
        else:
            up = base if i == segments[0] else g.names[g.parent[i]]
            h = hinges[i]
            for k in range(N_HINGES):
                link = f"{seg}_hinge{k}_link" if k < N_HINGES - 1 else seg
                xyz, angles = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
                if k == 0:
                    xyz, angles = g.socket_offset(i), rpy(g.R_parent_socket[i] @ R_rest[i])
                bounds = (h.lower[k], h.upper[k])
                _urdf_joint(
                    robot, f"{seg}_hinge{k}", "revolute", up, link, xyz, angles, h.axes[k], bounds
                )
                if link != seg:
                    _urdf_inertial(
                        ET.SubElement(robot, "link", name=link),
                        (0, 0, 0),
                        TINY_MASS,
                        np.eye(3) * TINY_INERTIA,
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
        "{seg}_hinge0, _hinge1, _hinge2 turn the segment from its standard-position frame "
        "(zero there; their singularity lies outside the limits); set them with diffbody's "
        "urdf_joint_values. The limits are a bounding box: check poses with diffbody's "
        "within_limits. Link {seg} is the twisted frame; spheres turn with the full twist. ",
    )


def urdf_joint_values(
    body: Body, pose: Pose, chain: Sequence[str] | None = None
) -> dict[str, float]:
    """Joint values of a pose for `export_urdf`'s file with the same `chain`.

    Per segment, the Euler angles (`_limit_sets.hinge_values`) of its rotation from its
    standard-position frame, Q = R_socket_rest^T R_socket_twisted, with R_socket_twisted its
    twisted frame in its socket in `forward` (so a spine target or a re-rooted body is
    placed as `forward` places it): zero at rest; q_0 and q_2 in [-pi, pi], q_1 in
    [-pi/2, pi/2]. For a pose within the limits they lie within the file's limits and away
    from the singularity; outside the limits they may reach it (the angles still give Q).

    Returns:
        {"{seg}_hinge0": q_0, "{seg}_hinge1": q_1, "{seg}_hinge2": q_2} (rad) for every
        exported segment but the whole body (fixed in the file; `pose.position` and the
        whole-body row are not used).
    """
    segments = _chain_segments(body, chain)
    shape = jnp.shape(pose.angles)
    if shape != (body.n_segments, 3):
        raise ValueError(f"urdf_joint_values: expected angles ({body.n_segments}, 3), got {shape}")
    _, _, R_socket_twisted = socket_rotations_batch(
        body, jax.tree.map(lambda x: jnp.asarray(x)[None], pose)
    )
    Q = rest_relative_rotations(body, np.asarray(R_socket_twisted[0]))
    hinges = euler_hinges(body)
    out = {}
    for i in segments:
        if body.parent[i] >= 0:
            values = hinge_values(hinges[i].axes, Q[i])
            out.update({f"{body.segment_names[i]}_hinge{k}": float(values[k]) for k in range(3)})
    return out
