"""Which sphere pairs of a body can touch (docs/design.md, section 10), decided once from
the structure and the limits, and their rest overlaps.

A pair of segments is never checked when
- no joint between them can move (they belong to one rigid group: joined by segments of
  zero swing and twist ranges that are not vertebrae, as the pelvis and its two halves):
  their distance never changes;
- they meet at a joint, counting each segment's rigid group as one (parent and child,
  siblings hanging from one joint, a thigh and the pelvis): their spheres meet at the joint
  by construction;
- both belong to the trunk (`Body.trunk`, counting each segment's rigid group as one: the
  pelvis with its two halves and the vertebrae with the neck): Bendspine spreads a bend
  over 18 joints of a few degrees each, so the slices cannot fold into each other.
Every other pair of spheres is checked. In the standard position the arms already sit up to
40 mm into the torso, hips and thighs (data/README.md, "Known properties"): each sphere pair's
rest overlap is its zero. The distance a pair reports against its allowance is
`d - min(d_rest, 0)`: a pair apart at rest may not touch, a pair overlapping at rest may not
overlap deeper than it does at rest.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._body import Body, rest_geometry


def rigid_groups(body: Body) -> list[int]:
    """Per segment, its rigid group: the first segment of the part of the tree it is joined
    to by joints that cannot move (zero swing and twist ranges, not a vertebra)."""
    lo, hi = np.asarray(body.swing_lo), np.asarray(body.swing_hi)
    tlo, thi = np.asarray(body.twist_lo), np.asarray(body.twist_hi)
    vertebrae = (
        set() if body.spine is None else {body.segment_index(n) for n in body.spine.segment_names}
    )
    group = list(range(body.n_segments))
    for s in range(body.n_segments):  # parents come first
        p = body.parent[s]
        moves = bool(np.any(hi[s] > lo[s]) or thi[s] > tlo[s] or s in vertebrae)
        if p >= 0 and not moves:
            group[s] = group[p]
    return group


def excluded_segment_pairs(body: Body) -> set[tuple[int, int]]:
    """Segment pairs (a < b) that are never checked (module docstring): rigidly joined,
    both in the trunk, or meeting at a joint of each other's rigid group (a thigh hangs
    from the pelvis's hip joint)."""
    group = rigid_groups(body)
    joints = [{body.proximal_joint[s], body.distal_joint[s]} for s in range(body.n_segments)]
    group_joints: dict[int, set[int]] = {}
    for s, g in enumerate(group):
        group_joints.setdefault(g, set()).update(joints[s])
    torso = {group[s] for s in body.trunk}  # the trunk's rigid groups
    out = set()
    for a in range(body.n_segments):
        for b in range(a + 1, body.n_segments):
            meet = bool(group_joints[group[a]] & group_joints[group[b]])
            if meet or group[a] == group[b] or (group[a] in torso and group[b] in torso):
                out.add((a, b))
    return out


@dataclass(frozen=True)
class SpherePairs:
    """The sphere pairs of a body that are checked (host side; NumPy).

    i, j: sphere indices (P,), i < j; segment_pair: each pair's row in `segments` (P,);
    segments: (S, 2) the segment pairs, a < b; rest: (P,) each pair's signed distance in the
    standard position (m); allowance: (P,) min(rest, 0), the pair's zero."""

    i: np.ndarray
    j: np.ndarray
    segment_pair: np.ndarray
    segments: np.ndarray
    rest: np.ndarray

    @property
    def allowance(self) -> np.ndarray:
        return np.minimum(self.rest, 0.0)

    def __len__(self) -> int:
        return len(self.i)


def sphere_pairs(body: Body, segments: Sequence[str] | None = None) -> SpherePairs:
    """The checked sphere pairs of the body, those with a sphere on one of `segments` (all
    when None): what `Target.no_contact` keeps apart and `contact_report` lists."""
    seg = np.asarray(body.sphere_segment, int)
    named = (
        set(range(body.n_segments))
        if segments is None
        else {body.segment_index(n) for n in segments}
    )
    skip = excluded_segment_pairs(body)
    a, b = np.triu_indices(body.n_spheres, 1)
    sa, sb = seg[a], seg[b]
    lo, hi = np.minimum(sa, sb), np.maximum(sa, sb)
    keep = (sa != sb) & (np.isin(sa, list(named)) | np.isin(sb, list(named)))
    keep &= ~np.asarray([(int(x), int(y)) in skip for x, y in zip(lo, hi)], bool)
    a, b, lo, hi = a[keep], b[keep], lo[keep], hi[keep]
    pairs, row = np.unique(np.stack([lo, hi], 1), axis=0, return_inverse=True)
    _, centers = rest_geometry(body)
    r = np.asarray(body.sphere_radii, float)
    rest = np.linalg.norm(centers[a] - centers[b], axis=-1) - r[a] - r[b]
    return SpherePairs(a, b, row.reshape(-1), pairs.reshape(-1, 2), rest)
