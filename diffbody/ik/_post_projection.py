"""The standard orientation as a post-projection after a solve (seed 000, "Standard
Orientation"; docs/design.md, section 4): whatever path the solver took, twists that no target
depends on go back to the standard orientation, with every joint where the solve put it."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._body import Body, Pose
from .._kinematics import forward
from .._limits import within_limits
from .._posture import pose_from_joints
from .._spine import bend_from_rest, with_spine_angles
from ..problem._constraints import Constraints
from ..problem._unknowns import Layout, point_segment

# A reset that breaks a limit by more than this (rad) is refused: the posture from joints
# rounds, and a twist exactly at its limit must stay admissible.
PROJECTION_TOL = 1e-6


def twists_to_keep(
    body: Body, layout: Layout, constraints: Constraints | None = None
) -> tuple[int, ...]:
    """Segments whose twist the projection keeps (static): the whole body, the vertebrae
    the spine moves, every segment at or above an off-axis effector (a feature or an axis
    target turns with the twists above it; joint positions never do), the parent of every
    hinge (resetting it would turn the hinge plane away from a bent joint), and the feet
    the `constraints` plant (their soles turn with their twists: a reset would lift them)."""
    names = body.segment_names
    spine = set(body.spine.segment_names) if body.spine is not None else set()
    keep = {0} | {i for i in layout.chain.segments if names[i] in spine}
    cog = body.n_joints + len(body.feature_names)
    if cog in layout.points:
        off_axis = list(range(body.n_segments))
    else:
        off_axis = [point_segment(body, i) for i in layout.points if i >= body.n_joints]
        off_axis += [
            layout.chain.segments[k]
            if k < layout.chain.size
            else layout.bases[k - layout.chain.size]
            for k in layout.axis_slot
        ]
    for seg in off_axis:
        keep |= set(body.path_to_top(seg))
    keep |= {int(body.parent[i]) for i in range(body.n_segments) if body.limit_kind[i] == "hinge"}
    if constraints is not None:
        keep |= set(constraints.feet)
    return tuple(sorted(keep))


def needs_projection(body: Body, layout: Layout, constraints: Constraints | None = None) -> bool:
    """Whether the solver moves a twist that the projection would reset."""
    seg = layout.chain.segments
    moved = {seg[k] for k in layout.twist}
    return bool(moved - set(twists_to_keep(body, layout, constraints)))


def keep_mask(body: Body, layout: Layout, constraints: Constraints | None = None) -> np.ndarray:
    """(n_seg,) `twists_to_keep` as a mask."""
    mask = np.zeros(body.n_segments, bool)
    mask[list(twists_to_keep(body, layout, constraints))] = True
    return mask


def project_to_standard(body: Body, pose: Pose, keep: np.ndarray | Array) -> Pose:
    """The pose with every twist outside `keep` (a mask over the segments, `keep_mask`)
    reset to the standard orientation, joint positions unchanged (the posture from
    joints); if a reset would break a limit, the pose is returned as it is. A pose with a
    spine target keeps it: its vertebrae are where the target bends them (`spine_as_angles`)
    and keep their twists, so that the segments hanging from them are projected from the
    frames `forward` gives them."""
    given, target = pose, pose.spine_target
    if target is not None:
        pose = spine_as_angles(body, pose)
        keep = keep | vertebrae_mask(body)
    fk = forward(body, pose)
    deviation = jnp.where(keep, pose.angles[:, 2], 0.0)
    W = fk.R_world_twisted[0]  # the whole body's frame is never projected
    standard = pose_from_joints(body, fk.joint_positions, W, deviation).angles
    projected = Pose(
        position=pose.position,
        angles=jnp.where(keep[:, None], pose.angles, standard),
        spine_target=target,
    )
    # The kept rows are the pose's own: only the reset ones are the projection's to check.
    ok = jnp.all(within_limits(body, projected, tol=PROJECTION_TOL) | keep)
    return jax.tree.map(lambda a, c: jnp.where(ok, a, c), projected, given)


def vertebrae_mask(body: Body) -> np.ndarray:
    """(n_seg,) the segments a spine target moves (none without a spine database)."""
    mask = np.zeros(body.n_segments, bool)
    if body.spine is not None:
        mask[[body.segment_index(s) for s in body.spine.segment_names]] = True
    return mask


def finish(body: Body, pose: Pose, keep: np.ndarray | Array | None, project=True) -> Pose:
    """The pose after the post-projection: `project_to_standard` keeping the twists of the
    mask `keep`, where `project` (a bool, or data); the pose as it is when `keep` is None
    (no projection asked for, or none needed)."""
    if keep is None:
        return pose
    projected = project_to_standard(body, pose, keep)
    if project is True:
        return projected
    return jax.tree.map(lambda a, c: jnp.where(project, a, c), projected, pose)


def spine_as_angles(body: Body, pose: Pose) -> Pose:
    """The pose without its spine target, its vertebrae set to the angles the target gives
    them (Bendspine from rest, as `forward` bends them)."""
    target = bend_from_rest(body.spine, pose.spine_target).angles
    return with_spine_angles(body, body.spine, pose, target)
