"""Several limbs at once in the limbs' phase (docs/design.md, section 6, "Limb chains").

With the trunk held as in the start, one limb's unknowns move none of another limb's
points, so a phase whose targets lie on several limbs is as many independent problems. Each
limb's targets are solved on its own limb chain's program and the answers are joined: a
reach with both hands compiles nothing a one-handed reach did not, where the whole tree's
program took 4.7 s of XLA (benchmarks/startup.py), and each limb tries its starts until it
reaches, not until every limb reaches from the same start.
"""

from typing import NamedTuple

import equinox as eqx
import numpy as np

from .._body import Body, Pose
from .._device_arrays import device_array
from ..problem._problem import stiffness_of
from ..problem._targets import TargetSet
from ..problem._tree import Plan
from ..problem._unknowns import Layout, make_layout, point_segment
from ._attempt import Attempt
from ._plans import make_limb_plan


class LimbGroup(NamedTuple):
    """One limb's share of a phase: its targets (their rows among the phase's), its own
    layout, its limb chain's layout and plan, and the segments it moves."""

    points: list[int]
    axes: list[int]
    targets: TargetSet
    layout: Layout
    planned: tuple[Layout, Plan]
    moves: list[int]


def moving_segments(layout: Layout) -> list[int]:
    """The segments whose swing or twist a layout frees."""
    slots = set(layout.swing_x + layout.swing_y + layout.twist)
    return sorted(layout.chain.segments[k] for k in slots)


def limb_groups(body: Body, layout: Layout, ts: TargetSet, closed: bool) -> list[LimbGroup] | None:
    """The limbs of a phase whose targets lie on two or more of them, each a limb chain
    (`_plans.make_limb_plan`); None where the phase is not that: one limb, constraints, the
    spine, the root, a whole-tree effector, or a limb longer than a limb chain. A target's
    limb is the topmost segment the phase moves on its path to the root. `closed`: whether
    the first start is the closed-form limb start."""
    if layout.spine or layout.root or layout.full or ts.constraints is not None:
        return None
    moves = set(moving_segments(layout))
    n_p = len(ts.point_index)
    segments = [point_segment(body, i) for i in ts.point_index] + list(ts.axis_segment)
    tops = [next((s for s in body.path_to_top(seg)[::-1] if s in moves), None) for seg in segments]
    if None in tops or len(set(tops)) < 2:
        return None
    groups, taken = [], set()
    for top in sorted(set(tops)):
        points = [j for j in range(n_p) if tops[j] == top]
        axes = [j for j in range(len(ts.axis_segment)) if tops[n_p + j] == top]
        sub = _subset(ts, points, axes)
        own = make_layout(body, sub.point_index, sub.axis_segment, moves, False, False)
        planned = make_limb_plan(body, own, sub, closed, stiffness_of(body, own))
        own_moves = moving_segments(own)
        if planned is None or taken & set(own_moves):
            return None
        taken |= set(own_moves)
        groups.append(LimbGroup(points, axes, sub, own, planned, own_moves))
    return groups


def _subset(ts: TargetSet, points: list[int], axes: list[int]) -> TargetSet:
    """The targets at rows `points` and `axes` of a set without constraints (host)."""

    def rows(a, at: list[int]):
        a = np.asarray(a)
        return device_array(a[np.asarray(at, int)], a.dtype)

    return TargetSet(
        point_index=tuple(ts.point_index[j] for j in points),
        point_xyz=rows(ts.point_xyz, points),
        point_weight=rows(ts.point_weight, points),
        axis_segment=tuple(ts.axis_segment[j] for j in axes),
        axis_local=rows(ts.axis_local, axes),
        axis_direction=rows(ts.axis_direction, axes),
        axis_weight=rows(ts.axis_weight, axes),
    )


def joined(start: Pose, ts: TargetSet, groups: list[LimbGroup], attempts: list, put) -> Attempt:
    """The phase's attempt from each limb's (host; one problem or rows of them): the start
    pose with every limb's segments as its attempt left them, the errors in the phase's
    target order, reached where every limb reached, the cost and steps summed. `put`: how
    a joined array is kept (`device_array` for a single solve, `np.asarray` for a batch)."""
    first = attempts[0]
    angles = np.array(np.broadcast_to(np.asarray(start.angles), np.shape(first.pose.angles)))
    lead = np.shape(first.ok)
    err_p = np.zeros(lead + (len(ts.point_index),), angles.dtype)
    err_a = np.zeros(lead + (len(ts.axis_segment),), angles.dtype)
    for g, a in zip(groups, attempts):
        angles[..., g.moves, :] = np.asarray(a.pose.angles)[..., g.moves, :]
        err_p[..., g.points] = np.asarray(a.err_p)[..., : len(g.points)]
        err_a[..., g.axes] = np.asarray(a.err_a)[..., : len(g.axes)]
    over = lambda field: np.stack([np.asarray(getattr(a, field)) for a in attempts])  # noqa: E731
    parts = (angles, err_p, err_a, over("ok").all(0), over("cost").sum(0), over("steps").sum(0))
    return eqx.tree_at(
        lambda a: (a.pose.angles, a.err_p, a.err_a, a.ok, a.cost, a.steps),
        first,
        tuple(put(v) for v in parts),
    )
