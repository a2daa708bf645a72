"""The whole-tree problem: one compiled reach round per body, the problem as data
(docs/design.md, section 6, "One program per body").

A phase's `Layout` (`_unknowns.make_layout`) decides on the host which unknowns a solve
moves and which segments it walks; compiled as it is, every effector set, segment subset and
phase is a program of its own. Here the compiled problem is the same for every solve of a
body: its layout is the whole tree (`tree_layout`: every segment walked, every unknown in the
free vector), and a `Plan` of arrays says what this solve moves and reaches for:

- which unknowns are free (the others stay at the start: `Problem.state` keeps them there),
  which vertebrae the spine target bends, and each unknown's stiffness;
- the effectors of the point and axis targets, padded to a bucket of rows (`bucket`: a pad
  row's target is not finite, so it takes no part, as any invalid target);
- the closed-form limb start's limbs (`_limb_start`), and whether the first start is it.

The phase's own layout stays the host's account of the solve (reach bounds, the
post-projection's twists). The free vector's order restricted to a phase's unknowns is the
phase's own order (both chains list segments by depth, then index), so the starts, pulls and
stiffnesses are the phase's, and the answers those of the phase's own program.
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._body import Body
from .._body_cache import RANGES, BodyCache
from .._device_arrays import device_array, take
from ..runs._batches import bucket
from ._targets import TargetSet
from ._unknowns import Layout, make_layout

# Target rows come in buckets of these sizes (points, axes), then doubling: a solve with a
# row count within its bucket runs the program of the bucket.
POINT_ROWS, AXIS_ROWS = 4, 2


class Plan(eqx.Module):
    """What one solve of the whole-tree problem moves and reaches for (data, `make_plan`).

    free: which entries of the free vector move; vertebrae: which the spine target bends
    (`Layout.spine` order); moves: which segments' angles the answer takes from the solve;
    stiffness: per entry (`_problem.stiffness_of`); closed: the first start is the
    closed-form limb start; point_effector (P,): into [joints, features]; axis_segment
    (A,); the limbs (L = P rows, `use` False on pads): their point target row, effector,
    upper and hinge segments and free-vector entries (L, 4: upper swing_x, swing_y, hinge
    flexion, upper twist; -1 where not free).
    """

    free: Bool[Array, " n_free"]
    vertebrae: Bool[Array, " n_vertebrae"]
    moves: Bool[Array, " n_seg"]
    stiffness: Float[Array, " n_free"]
    closed: Bool[Array, ""]
    point_effector: Int[Array, " P"]
    axis_segment: Int[Array, " A"]
    limb_use: Bool[Array, " L"]
    limb_row: Int[Array, " L"]
    limb_effector: Int[Array, " L"]
    limb_upper: Int[Array, " L"]
    limb_hinge: Int[Array, " L"]
    limb_entries: Int[Array, "L 4"]


def tree_layout(body: Body) -> Layout:
    """The whole tree's layout: every segment walked from the world, every swing and twist
    with a range, the spine as its target, the root's placement; every segment readable
    by the constraints. One per body structure and limits (cached: host work of
    milliseconds)."""
    return _TREES.get(body, None, lambda: _tree_layout(body))


_TREES = BodyCache(RANGES, size=16)


def _tree_layout(body: Body) -> Layout:
    n, cog = body.n_segments, body.n_joints + len(body.feature_names)
    every = make_layout(body, (cog,), (), range(n), spine=True, root=True)
    return dataclasses.replace(
        every,
        full=body.root_joint != body.default_root_joint,
        points=(),
        point_slot=(),
        read_slot=tuple(every.chain.position(s) for s in range(n)),
    )


def tree_entries(tree: Layout, phase: Layout) -> np.ndarray | None:
    """(phase.n_free,) where each of the phase's unknowns sits in the tree's free vector;
    None when one has no place there (a vertebra free on its own, without the spine)."""
    offsets = np.cumsum((0,) + tree.sizes)
    t_seg, p_seg = tree.chain.segments, phase.chain.segments
    out = []
    for part, (t_part, p_part) in enumerate(
        zip((tree.swing_x, tree.swing_y, tree.twist), (phase.swing_x, phase.swing_y, phase.twist))
    ):
        where = {t_seg[k]: j for j, k in enumerate(t_part)}
        for k in p_part:
            if p_seg[k] not in where:
                return None
            out.append(offsets[part] + where[p_seg[k]])
    if phase.spine:
        if not tree.spine:
            return None
        out += list(offsets[3] + np.arange(3))
    if phase.root:
        out += list(offsets[4] + np.arange(6))
    return np.asarray(out, int)


def targets_rows(targets: TargetSet) -> tuple[int, int]:
    """The buckets (point rows, axis rows) of a target set."""
    return (
        bucket(len(targets.point_index), POINT_ROWS),
        bucket(len(targets.axis_segment), AXIS_ROWS),
    )


def padded_targets(targets: TargetSet) -> TargetSet:
    """The target set padded to its buckets (host): pad rows are not finite (so they take
    no part) and weigh nothing; the effectors are the plan's (data), not the set's."""
    P, A = targets_rows(targets)

    def pad(a, rows: int, fill: float) -> Array:
        a = np.asarray(a)
        extra = np.full((rows - a.shape[0],) + a.shape[1:], fill, a.dtype)
        return device_array(np.concatenate([a, extra]), a.dtype)

    return TargetSet(
        point_index=(),
        point_xyz=pad(targets.point_xyz, P, np.nan),
        point_weight=pad(targets.point_weight, P, 0.0),
        axis_segment=(),
        axis_local=pad(targets.axis_local, A, 0.0),
        axis_direction=pad(targets.axis_direction, A, np.nan),
        axis_weight=pad(targets.axis_weight, A, 0.0),
        constraints=targets.constraints,
    )


def effector_rows(body: Body, tree: Layout, plan: Plan, targets: TargetSet) -> list[tuple]:
    """The point kernel's rows (slots, offsets, heights) of the plan's targets, as data:
    the point effectors (P; a joint j >= 1 ends segment j - 1, joint 0 is the whole body's
    origin, a feature lies on its sphere), then each axis target as two points, at its local
    direction and at its segment's proximal joint (A each)."""
    n_j, n_f = body.n_joints, len(body.feature_names)
    slot_of = np.asarray(tree.read_slot, int)
    e = plan.point_effector
    joint = e < n_j
    seg = jnp.maximum(e - 1, 0)
    z = jnp.where(e > 0, body.lengths[seg], 0.0)
    offset, height = jnp.stack([0.0 * z, 0.0 * z, z], axis=-1), z
    if n_f:
        f = jnp.clip(e - n_j, 0, n_f - 1)
        sph = take(np.asarray(body.feature_sphere, int), f)
        origin = body.sphere_origins[sph]
        on_sphere = origin + body.sphere_radii[sph][:, None] * body.feature_directions[f]
        seg = jnp.where(joint, seg, take(np.asarray(body.sphere_segment, int), sph))
        offset = jnp.where(joint[:, None], offset, on_sphere)
        height = jnp.where(joint, height, origin[:, 2])
    a = plan.axis_segment
    s_a = take(slot_of, a)
    zeros = jnp.zeros_like(targets.axis_local)
    return [
        (take(slot_of, seg), offset, height),
        (
            jnp.concatenate([s_a, s_a]),
            jnp.concatenate([targets.axis_local, zeros]),
            jnp.concatenate([body.lengths[a], zeros[:, 0]]),
        ),
    ]
