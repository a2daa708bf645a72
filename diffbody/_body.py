"""The body model (seed 000, docs/design.md, section 2): segments, joints, spheres, features,
limits, and the spine database (seed 004) that drives its vertebrae.

A `Body` is an immutable pytree. Its static fields (names, parent indices, levels of the
tree, kinds) are compile-time constants; its arrays (lengths, frames, limits, spheres,
masses) can be differentiated, fitted and batched. The chain environment ->
"center_of_gravity" joint -> "whole_body" segment -> root joint of seed 000 (Fig. 6) is
explicit: segment 0 is always "whole_body" and joint 0 always "center_of_gravity".
"""

import dataclasses
import difflib
from collections.abc import Iterable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._orientation import vector_to_azimuth_polar

WHOLE_BODY = "whole_body"
CENTER_OF_GRAVITY = "center_of_gravity"
CENTER_OF_GRAVITY_INDEX = 0  # joint 0: translates the whole body
# Columns of a pose's angle array.
THETA, PHI, TAU = 0, 1, 2
# The parts the solver gives a role are found by these endings of their names, the default
# human body's ("left_foot", "right_thigh"): a child's or a robot's body takes a role by
# naming its segments so. `Body.feet`: the segments standing on the floor; `Body.thighs`:
# the legs' tops, below which a standing body's knees and ankles are stiff.
FOOT, THIGH = "_foot", "_thigh"


def unknown_name_error(kind: str, name: str, valid: tuple[str, ...]) -> KeyError:
    """A KeyError that lists the valid names, closest first."""
    close = difflib.get_close_matches(name, valid, n=3, cutoff=0.5)
    hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    return KeyError(f"unknown {kind} {name!r}.{hint} Valid {kind}s: {', '.join(valid)}")


class Pose(eqx.Module):
    """A posture of a body: where it stands and every segment's orientation.

    `angles[i] = (theta, phi, tau)` of segment i (rad): theta, phi the azimuth and polar
    angle of its direction in its socket frame (seed 000), tau its twist deviation from the
    standard orientation. Row 0 is the whole body ("stance" orientation, measured in the
    world). `position` places the root joint in the world (m).
    """

    position: Float[Array, "3"]
    angles: Float[Array, "n_seg 3"]
    # Optional Bendspine target (rad, the sum of the spine's joint angles): when given,
    # `forward` bends the body's spine database to it from rest and overrides the vertebra rows.
    spine_target: Float[Array, "3"] | None = None


class Spine(eqx.Module):
    """A spine database (seed 004, "Spine database"): per joint the rest angles and the
    limits of the three rotations (flexion, axial, lateral; see `diffbody.bendspine`), disc
    heights and flexion-axis offsets; per vertebra its size. Build it with
    `diffbody.load_spine`."""

    joint_names: tuple[str, ...] = eqx.field(static=True)  # "C7_T1", ..., "L5_S1"
    initiator: int = eqx.field(static=True)  # default initiator of a Pose's spine_target
    segment_names: tuple[str, ...] = eqx.field(static=True)  # body segment each joint moves
    vertebra_names: tuple[str, ...] = eqx.field(static=True)  # "T1", ..., "L5"
    rest: Float[Array, "n_joint 3"]  # rad, the standing posture
    lower: Float[Array, "n_joint 3"]  # rad, limits (absolute joint angles)
    upper: Float[Array, "n_joint 3"]  # rad
    disc_heights: Float[Array, " n_joint"]  # m
    flexion_axis_offsets: Float[Array, "n_joint 2"]  # m, (x forward, z up) from the disc centre
    vertebra_sizes: Float[Array, "n_vert 3"]  # m, depth (x), breadth (y), height (z)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def joint_index(self, name: str) -> int:
        """Index of a spine joint ("T6_T7") or of the vertebra it moves ("T6", "neck")."""
        if name in self.joint_names:
            return self.joint_names.index(name)
        if name in self.segment_names:
            return self.segment_names.index(name)
        raise unknown_name_error("spine joint", name, self.joint_names + self.segment_names)


class Body(eqx.Module):
    """A sphere-skinned articulated body (seed 000). Build it with `diffbody.load_body`.

    Frames: every segment's cross of axes has its origin at the proximal joint and +Z toward
    the distal joint. `R_socket_rest[i]` is that frame in the standard position, expressed in
    the segment's socket frame, which coincides with the world frame in the standard
    position; `R_parent_socket[i]` turns the parent's twisted frame into segment i's socket.
    """

    name: str = eqx.field(static=True)
    source: str = eqx.field(static=True)
    segment_names: tuple[str, ...] = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)
    parent: tuple[int, ...] = eqx.field(static=True)  # -1: the environment (world)
    proximal_joint: tuple[int, ...] = eqx.field(static=True)
    distal_joint: tuple[int, ...] = eqx.field(static=True)
    levels: tuple[tuple[int, ...], ...] = eqx.field(static=True)  # segments by tree depth
    standard_kind: tuple[str, ...] = eqx.field(static=True)  # "swing" or a limb name
    limit_kind: tuple[str, ...] = eqx.field(static=True)  # "free", "box", "cone", "hinge"
    sphere_segment: tuple[int, ...] = eqx.field(static=True)
    feature_names: tuple[str, ...] = eqx.field(static=True)  # "segment.feature"
    feature_sphere: tuple[int, ...] = eqx.field(static=True)
    root_joint: int = eqx.field(static=True)  # the joint that `Pose.position` places
    default_root_joint: int = eqx.field(static=True)  # distal joint of "whole_body"

    lengths: Float[Array, " n_seg"]  # m, proximal to distal joint ("distance")
    R_parent_socket: Float[Array, "n_seg 3 3"]  # parent twisted frame -> socket frame
    R_socket_rest: Float[Array, "n_seg 3 3"]  # standard-position cross of axes in the socket
    swing_lo: Float[Array, "n_seg 2"]  # rad, lower bounds of the swing vector (w_x, w_y)
    swing_hi: Float[Array, "n_seg 2"]  # rad, upper bounds
    swing_max: Float[Array, " n_seg"]  # rad, cone radius about the standard direction
    twist_lo: Float[Array, " n_seg"]  # rad, "negative limit" of the twist
    twist_hi: Float[Array, " n_seg"]  # rad, "positive limit"
    masses: Float[Array, " n_seg"]  # kg
    centroids: Float[Array, "n_seg 3"]  # m, segment cross of axes
    sphere_origins: Float[Array, "n_sph 3"]  # m, cross of axes of the sphere's segment
    sphere_radii: Float[Array, " n_sph"]  # m
    feature_directions: Float[Array, "n_feat 3"]  # unit, cross of axes of the segment
    enclosure_z: Float[Array, " n_seg"]  # m, enclosure centre (0, 0, z) in the cross of axes
    enclosure_radii: Float[Array, " n_seg"]  # m
    rest_position: Float[Array, "3"]  # m, the root joint in the standard position
    R_world_pin_rest: Float[Array, "3 3"]  # pinned frame at the root joint, standard position
    spine: Spine | None = None  # the spine database driving the vertebrae, if any

    # --- name lookups (host side, outside jit) -------------------------------------------
    @property
    def n_segments(self) -> int:
        return len(self.segment_names)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_spheres(self) -> int:
        return len(self.sphere_segment)

    def segment_index(self, name: str) -> int:
        """Index of a segment by name (raises KeyError listing the valid names)."""
        try:
            return self.segment_names.index(name)
        except ValueError:
            raise unknown_name_error("segment", name, self.segment_names) from None

    def joint_index(self, name: str) -> int:
        """Index of a joint by name (raises KeyError listing the valid names)."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise unknown_name_error("joint", name, self.joint_names) from None

    def feature_index(self, name: str) -> int:
        """Index of a feature by its "segment.feature" name."""
        try:
            return self.feature_names.index(name)
        except ValueError:
            raise unknown_name_error("feature", name, self.feature_names) from None

    def segment_spheres(self, name: str) -> np.ndarray:
        """Indices of the surface spheres of a segment."""
        i = self.segment_index(name)
        return np.flatnonzero(np.asarray(self.sphere_segment) == i)

    def children(self, name: str) -> tuple[str, ...]:
        """Names of the segments hanging from a segment's distal joint."""
        i = self.segment_index(name)
        return tuple(n for n, p in zip(self.segment_names, self.parent) if p == i)

    # --- the tree and the roles of its parts (host side, from the static structure) -------
    # Plain methods, not cached properties: equinox puts a cached property's value in the
    # pytree's structure, so caching would change `jax.tree.structure(body)` (a new program
    # for the same body, a new `tree_hash`). Each costs microseconds on a body's tree.
    def path_to_top(self, seg: int) -> tuple[int, ...]:
        """The segment and its ancestors, from it up to the whole body."""
        path = []
        while seg >= 0:
            path.append(seg)
            seg = self.parent[seg]
        return tuple(path)

    def below(self, segments: Iterable[int]) -> frozenset[int]:
        """The segments hanging from `segments`, directly or further down (not themselves)."""
        top = set(segments)
        return frozenset(s for s in range(self.n_segments) if top & set(self.path_to_top(s)[1:]))

    @property
    def trunk(self) -> frozenset[int]:
        """The whole body, the spine's segments (the vertebrae and the neck) and every
        segment above them (the pelvis); the whole body alone without a spine database.
        The limbs are what hangs from it."""
        names = () if self.spine is None else self.spine.segment_names
        paths = [self.path_to_top(self.segment_index(n)) for n in names]
        return frozenset({0}.union(*paths))

    @property
    def feet(self) -> tuple[int, ...]:
        """The segments a standing body stands on, in segment order: those whose names end
        in `FOOT` ("left_foot", "right_foot")."""
        return tuple(i for i, n in enumerate(self.segment_names) if n.endswith(FOOT))

    @property
    def thighs(self) -> tuple[int, ...]:
        """The tops of the legs, in segment order: the segments whose names end in `THIGH`
        ("left_thigh", "right_thigh"); `below(thighs)` are the shanks and the feet."""
        return tuple(i for i, n in enumerate(self.segment_names) if n.endswith(THIGH))

    @property
    def local_directions(self) -> Float[Array, "n_seg 3 3"]:
        """Each segment's "forward", "left" and "up" (rows) in its own cross of axes: the
        world directions of the standard position (seed 000: "the negative Z-axis is up
        for the lower arm")."""
        # Rows of R_socket_rest are the world (= socket, at rest) axes in the segment's frame.
        return self.R_socket_rest

    # --- poses ------------------------------------------------------------------------------
    def rest_pose(self) -> Pose:
        """The standard position: upright, feet flat on the ground (z = 0), toes forward,
        arms at the sides with palms toward the thighs, the root joint above the world
        origin, facing +X."""
        return _rest_pose(self.R_socket_rest, self.rest_position)

    def with_root(self, joint: str) -> "Body":
        """The same body placed by another joint (seed 000: "any other joint may be
        substituted as the root, since the tree structure is undirected").

        `Pose.position` then places `joint`, and the whole body's orientation (pose row 0)
        sets the frame of the segment ending at that joint; everything else hangs from it.
        Joint angles keep their meaning (each segment in the socket of its default proximal
        segment), so limits and standard orientations are unchanged: re-rooting changes
        which part of the body stays put when the angles change. E.g. with root
        "left_toe_tip", bending the left ankle tilts the whole body over a planted left foot.
        """
        j = self.joint_index(joint)
        if j == CENTER_OF_GRAVITY_INDEX:
            raise ValueError(
                f"with_root: {joint!r} is the translating joint of the whole body; "
                "choose a joint of the body tree"
            )
        p, _ = rest_geometry(self)
        seg = self.distal_joint.index(j)
        return dataclasses.replace(
            self,
            root_joint=j,
            rest_position=jnp.asarray(p[j]),
            R_world_pin_rest=self.R_socket_rest[seg],
        )


def rest_geometry(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and sphere centres (NumPy, world) of the standard position, the root
    joint at `body.rest_position`: every frame is the standard cross of axes, so no
    kinematics is needed."""
    R = np.asarray(body.R_socket_rest)
    L = np.asarray(body.lengths)
    p = np.zeros((body.n_joints, 3))
    for i in range(body.n_segments):  # breadth first: proximal joints come first
        p[body.distal_joint[i]] = p[body.proximal_joint[i]] + L[i] * R[i][:, 2]
    p += np.asarray(body.rest_position) - p[body.root_joint]
    seg = np.asarray(body.sphere_segment, dtype=int)
    centers = p[np.asarray(body.proximal_joint)[seg]] + np.einsum(
        "kij,kj->ki", R[seg], np.asarray(body.sphere_origins)
    )
    return p, centers


def without_names(body: Body) -> Body:
    """The body without its name and source, static fields no kernel reads: every body of one
    structure then shares one compiled function (fits, rendering, descriptors)."""
    return dataclasses.replace(body, name="", source="")


@jax.jit
def _rest_pose(R_socket_rest: Array, rest_position: Array) -> Pose:
    """`Body.rest_pose`, compiled once (eagerly it is a dozen small programs)."""
    theta, phi, _ = vector_to_azimuth_polar(R_socket_rest[:, :, 2])
    angles = jnp.stack([theta, phi, jnp.zeros_like(theta)], axis=-1)
    return Pose(position=rest_position, angles=angles)
