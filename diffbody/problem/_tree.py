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

A limb's chain has a program of its own, small enough for batches (`limb_layout`: a path
of `LIMB_SLOTS` segments, each with its swing and twist in the free vector): the plan then
names the chain's segments and the one it hangs from (data), so every arm or leg reach of a
body shares it, whatever its effector or segment subset; a whole-tree round walks every
segment for each residual, ten times the work of a limb's four.

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
from .._chain import Chain
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
    flexion, upper twist; -1 where not free). On a limb chain (`limb_layout`): chain (m,),
    the global segment of each chain slot, base (1,), the one the chain hangs from, and
    slot_of (n_seg,), each segment's chain slot (m: the base); None on the whole tree.
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
    chain: Int[Array, " m"] | None = None
    base: Int[Array, " 1"] | None = None
    slot_of: Int[Array, " n_seg"] | None = None


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


# The longest limb chain with a program of its own (`limb_layout`); shorter chains take the
# program of `LIMB_SLOTS[0]` slots or, past it, of the next.
LIMB_SLOTS = (4, 6)


def limb_layout(slots: int) -> Layout:
    """The layout of a limb chain of `slots` segments (a path, slot k hanging from slot
    k - 1 and slot 0 from the one base), each with its swing vector and twist in the free
    vector; its segments are the plan's (data). The same for every body."""
    chain = Chain(
        segments=tuple(range(slots)),
        parent_slot=(slots,) + tuple(range(slots - 1)),
        levels=tuple((k,) for k in range(slots)),
        n_bases=1,
    )
    every = tuple(range(slots))
    return Layout(
        chain=chain,
        bases=(slots,),  # a placeholder: the plan's base (data) is the segment
        swing_x=every,
        swing_y=every,
        twist=every,
        spine=(),
        spine_rows=(),
        root=False,
        full=False,
        points=(),
        point_slot=(),
        axis_slot=(),
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


def targets_rows(targets: TargetSet, limb: bool = False) -> tuple[int, int]:
    """The buckets (point rows, axis rows) of a target set: on a limb chain (`limb`) the
    rows it has, rounded up to a power of two (one axis row at least: a hand's position
    with or without its direction, one program)."""
    n_p, n_a = len(targets.point_index), len(targets.axis_segment)
    if limb:
        return bucket(n_p), bucket(n_a)
    return bucket(n_p, POINT_ROWS), bucket(n_a, AXIS_ROWS)


def padded_targets(targets: TargetSet, limb: bool = False) -> TargetSet:
    """The target set padded to its buckets (host, `targets_rows`): pad rows are not finite
    (so they take no part) and weigh nothing; the effectors are the plan's (data), not the
    set's."""
    P, A = targets_rows(targets, limb)

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


def effector_rows(body: Body, slot_of, plan: Plan, targets: TargetSet) -> list[tuple]:
    """The point kernel's rows (slots, offsets, heights) of the plan's targets, as data:
    the point effectors (P; a joint j >= 1 ends segment j - 1, joint 0 is the whole body's
    origin, a feature lies on its sphere), then each axis target as two points, at its local
    direction and at its segment's proximal joint (A each). `slot_of` (n_seg,): each
    segment's slot (`Problem.slot_of`)."""
    n_j, n_f = body.n_joints, len(body.feature_names)
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
