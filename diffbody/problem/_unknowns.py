"""The unknowns of a reach problem and their bounded maps (docs/design.md, section 6).

Each unknown is a bounded map of a free variable u, so the solver cannot leave the
admissible set and the limits hold exactly: v = mid + half sin(u) into [lo, hi] (unlike a
logistic squash it reaches its bounds at finite u, and its slope never vanishes inside), and
a swing vector is then pulled radially into its cone. The free vector is
[swing_x | swing_y | twist | spine target (3) | root placement (6)], each part present only
when something in it can move.
"""

from collections.abc import Iterable
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body
from .._chain import Chain, make_chain


def squash(u: Array, lo: Array, hi: Array) -> Array:
    """The bounded map mid + half sin(u) into [lo, hi]."""
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * jnp.sin(u)


def unsquash(v: Array, lo: Array, hi: Array) -> Array:
    """A free variable for the value v, kept off the bounds: at a bound the map's slope is
    zero, and a limb straight at its stop (the elbow in the standard position) is a singular
    start."""
    f = jnp.clip((2 * v - lo - hi) / jnp.where(hi > lo, hi - lo, 1.0), -0.9, 0.9)
    return jnp.arcsin(f)


def into_cone(w: Float[Array, "k 2"], swing_max: Float[Array, " k"]) -> Float[Array, "k 2"]:
    """Swing vectors pulled radially into their cones |w| <= swing_max."""
    norm2 = jnp.sum(w * w, axis=-1)
    over = norm2 > swing_max**2
    safe = jnp.where(over, norm2, 1.0)
    return w * jnp.where(over, swing_max / jnp.sqrt(safe), 1.0)[:, None]


@dataclass(frozen=True)
class Layout:
    """Which quantities are unknowns and which segments one residual evaluation walks
    (static). The live chain holds every segment at or below an unknown on an effector's
    path; everything above is read once from the start (the bases).

    swing_x, swing_y, twist: chain positions whose component is free.
    spine: chain positions of the vertebrae the spine target moves, with `spine_rows`
        their rows in the spine database (empty: the spine stays as in the start).
    root: the whole body's placement is free (translation and rotation).
    full: the whole tree is walked (a center-of-gravity target, a re-rooted body).
    point_slot, axis_slot: the slot of each effector's segment (chain or base).
    """

    chain: Chain
    bases: tuple[int, ...]  # global segments whose start state the chain hangs from; -1 world
    swing_x: tuple[int, ...]
    swing_y: tuple[int, ...]
    twist: tuple[int, ...]
    spine: tuple[int, ...]
    spine_rows: tuple[int, ...]
    root: bool
    full: bool
    points: tuple[int, ...]
    point_slot: tuple[int, ...]
    axis_slot: tuple[int, ...]
    read_slot: tuple[int, ...] = ()  # the slot of every segment (-1: not read), constraints
    standing: bool = False  # the root is free and the legs carry it (feet on the floor)

    @property
    def sizes(self) -> tuple[int, int, int, int, int]:
        return (
            len(self.swing_x),
            len(self.swing_y),
            len(self.twist),
            3 if self.spine else 0,
            6 if self.root else 0,
        )

    @property
    def n_free(self) -> int:
        return sum(self.sizes)

    def split(self, x: Array) -> tuple[Array, Array, Array, Array, Array]:
        """The free vector's parts: swing_x, swing_y, twist, spine, root."""
        cuts = np.cumsum(self.sizes)[:-1]
        return tuple(jnp.split(x, cuts))  # type: ignore[return-value]


def point_segment(body: Body, index: int) -> int:
    """The segment a point effector rides on (joint j >= 1 ends segment j - 1; joint 0 and
    the center of gravity: the whole body; a feature: its sphere's segment)."""
    n_j = body.n_joints
    if index < n_j:
        return max(index - 1, 0)
    if index - n_j >= len(body.feature_names):
        return 0
    return body.sphere_segment[body.feature_sphere[index - n_j]]


def moves_everything(body: Body, points: Iterable[int]) -> bool:
    """Whether every segment moves the effectors `points`: the center of gravity is among
    them, or the body hangs from a joint other than its default root."""
    cog = body.n_joints + len(body.feature_names)
    return cog in points or body.root_joint != body.default_root_joint


def segments_on_path(body: Body, points: Iterable[int], axes: Iterable[int] = ()) -> set[int]:
    """The segments whose joints move the effectors `points` (into [joints, features, center
    of gravity]) or the axis segments `axes`: their paths to the top, or every segment."""
    points = tuple(points)
    if moves_everything(body, points):
        return set(range(body.n_segments))
    eff = [point_segment(body, i) for i in points] + list(axes)
    return {s for e in eff for s in body.path_to_top(e)}


def make_layout(
    body: Body,
    points: Iterable[int],
    axes: Iterable[int],
    movable: Iterable[int],
    spine: bool,
    root: bool,
    read: Iterable[int] = (),
    feet: Iterable[int] = (),
) -> Layout:
    """The layout for effectors `points` (into [joints, features, center of gravity]) and
    axis segments `axes`, with `movable` segments free within their ranges, the spine as its
    target when `spine`, the whole body's placement when `root`. Constraints add segments
    whose points are `read` (walked when something above them moves, else read from the
    start) and `feet` on the floor, whose paths are unknowns when the root is free (the
    legs then carry the body: otherwise they are only read)."""
    points, axes = tuple(int(i) for i in points), tuple(int(i) for i in axes)
    full = moves_everything(body, points)
    feet = tuple(int(i) for i in feet)
    legs = feet if root else ()
    on_path = segments_on_path(body, points, tuple(axes) + legs)
    read = sorted(set(int(i) for i in read) | set(feet))
    eff = [point_segment(body, i) for i in points] + list(axes) + read
    spine_segs = set(body.spine.segment_names) if (spine and body.spine is not None) else set()
    names = body.segment_names
    lo, hi = np.asarray(body.swing_lo), np.asarray(body.swing_hi)
    tlo, thi = np.asarray(body.twist_lo), np.asarray(body.twist_hi)
    movable = {int(i) for i in movable} & on_path - {0}
    spine_on = {i for i in movable if names[i] in spine_segs}
    free_swing_x = {i for i in movable - spine_on if hi[i, 0] > lo[i, 0]}
    free_swing_y = {i for i in movable - spine_on if hi[i, 1] > lo[i, 1]}
    free_twist = {i for i in movable - spine_on if thi[i] > tlo[i]}
    moving = free_swing_x | free_swing_y | free_twist | spine_on | ({0} if root else set())
    if full:
        live = set(range(body.n_segments))
    else:
        live = {s for e in eff for s in body.path_to_top(e) if _moves_above(body, s, moving)}
    bases = sorted({int(body.parent[s]) for s in live if int(body.parent[s]) not in live})
    bases += sorted({s for s in eff if s not in live} - set(bases))
    chain = make_chain(body.parent, live, bases)
    pos = {s: k for k, s in enumerate(chain.segments)}

    def slot(s: int) -> int:
        return pos[s] if s in pos else chain.size + bases.index(s)

    spine_rows = []
    if spine_on:
        order = list(body.spine.segment_names)
        spine_rows = sorted(order.index(names[i]) for i in spine_on)
    return Layout(
        chain=chain,
        bases=tuple(bases),
        swing_x=tuple(sorted(pos[i] for i in free_swing_x)),
        swing_y=tuple(sorted(pos[i] for i in free_swing_y)),
        twist=tuple(sorted(pos[i] for i in free_twist)),
        spine=tuple(pos[body.segment_index(body.spine.segment_names[r])] for r in spine_rows),
        spine_rows=tuple(spine_rows),
        root=root,
        full=full,
        points=points,
        point_slot=tuple(slot(point_segment(body, i)) for i in points),
        axis_slot=tuple(slot(s) for s in axes),
        read_slot=tuple(slot(s) if s in read else -1 for s in range(body.n_segments))
        if read
        else (),
        standing=bool(legs),
    )


def whole_tree_layout(body: Body) -> Layout:
    """Every segment free within its limits, the spine as its target, the root placement
    free: the whole tree walked (the center of gravity as the effector asks for it)."""
    everything = [body.n_joints + len(body.feature_names)]
    return make_layout(body, everything, [], range(body.n_segments), spine=True, root=True)


def _moves_above(body: Body, seg: int, moving: set[int]) -> bool:
    return any(s in moving for s in body.path_to_top(seg))
