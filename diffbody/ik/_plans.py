"""A phase's plan (host, docs/design.md, section 6, "One program per body", "Limb
chains"): which unknowns the phase moves, its limbs and effectors, as the data of the one
compiled round of the whole tree or of a limb chain (`_tree`)."""

import equinox as eqx
import numpy as np

from .._body import Body
from .._device_arrays import device_array
from ..problem._problem import stiffness_of
from ..problem._targets import TargetSet
from ..problem._tree import (
    LIMB_SLOTS,
    Plan,
    limb_layout,
    padded_targets,
    targets_rows,
    tree_entries,
)
from ..problem._unknowns import Layout
from ._attempt import Attempt
from ._limb_start import limbs


def fits_tree(body: Body, targets: TargetSet) -> bool:
    """Whether a solve runs on the whole-tree program: a body hanging from its default root
    and no center-of-gravity target (whose 37 centroids are a program of their own)."""
    cog = body.n_joints + len(body.feature_names)
    return body.root_joint == body.default_root_joint and cog not in targets.point_index


def make_plan(
    body: Body, tree: Layout, phase: Layout, targets: TargetSet, closed: bool, stiffness
) -> Plan | None:
    """The plan of one phase (host): its unknowns, limbs and effectors on the whole tree's
    free vector, padded to the targets' buckets. `stiffness`: the phase's, per unknown.
    None when the phase has no place on the tree (`tree_entries`)."""
    entries = tree_entries(tree, phase)
    if entries is None:
        return None
    spine_rows = set(phase.spine_rows)
    vertebrae = np.asarray([r in spine_rows for r in tree.spine_rows], bool)
    return _plan(body, phase, targets, closed, stiffness, entries, tree.n_free, vertebrae)


def make_limb_plan(
    body: Body, phase: Layout, targets: TargetSet, closed: bool, stiffness
) -> tuple[Layout, Plan] | None:
    """The layout and plan of a phase on a limb chain's program (`_tree.limb_layout`): its
    chain's segments, padded to the program's slots by repeats of the last, which nothing
    reads or moves. None when the phase is not a limb chain: a path of at most
    `LIMB_SLOTS[-1]` segments hanging from one segment below the world, its effectors on
    it, and no spine, root, constraint or whole-tree effector."""
    chain, m = phase.chain, phase.chain.size
    path = chain.parent_slot == (m,) + tuple(range(m - 1))
    if not (0 < m <= LIMB_SLOTS[-1] and path and chain.n_bases == 1 and phase.bases[0] >= 0):
        return None
    if phase.spine or phase.root or phase.full or phase.read_slot or targets.constraints:
        return None
    if any(s >= m for s in phase.point_slot + phase.axis_slot):
        return None
    K = next(k for k in LIMB_SLOTS if m <= k)
    limb = limb_layout(K)
    at = {"swing_x": 0, "swing_y": K, "twist": 2 * K}
    entries = [at[part] + k for part in at for k in getattr(phase, part)]
    plan = _plan(body, phase, targets, closed, stiffness, entries, limb.n_free, [], True)
    segments = list(chain.segments) + [chain.segments[-1]] * (K - m)
    slot_of = np.zeros(body.n_segments, int)
    slot_of[list(chain.segments)] = np.arange(m)
    slot_of[phase.bases[0]] = K
    return limb, eqx.tree_at(
        lambda p: (p.chain, p.base, p.slot_of),
        plan,
        (
            device_array(segments, int),
            device_array(phase.bases[:1], int),
            device_array(slot_of, int),
        ),
        is_leaf=lambda x: x is None,
    )


def limb_plans(body: Body, layouts: list[Layout], templates: list[TargetSet], closed) -> list:
    """Per phase of a batch, its limb chain's layout and plan (`make_limb_plan`) and its
    targets padded to their buckets, or None: the phase compiles its own layout (the
    trunk's, standing; a chain of several limbs). `closed`: per phase, whether its first
    start is the closed-form limb start."""
    plans = []
    for layout, ts, first in zip(layouts, templates, closed):
        limb = None
        if not layout.standing and body.root_joint == body.default_root_joint:
            limb = make_limb_plan(body, layout, ts, first, stiffness_of(body, layout))
        plans.append(None if limb is None else (*limb, padded_targets(ts, limb=True)))
    return plans


def _plan(body, phase, targets, closed, stiffness, entries, n_free, vertebrae, limb=False):
    """A phase's plan on a free vector of `n_free` entries, the phase's unknowns at
    `entries` (`make_plan`, `make_limb_plan`)."""
    entries = np.asarray(entries, int)
    free = np.zeros(n_free, bool)
    free[entries] = True
    stiff = np.ones(n_free)
    stiff[entries] = stiffness
    moves = np.zeros(body.n_segments, bool)
    segs = phase.chain.segments
    moves[[segs[k] for k in set(phase.swing_x + phase.swing_y + phase.twist)]] = True
    P, A = targets_rows(targets, limb)
    found = limbs(body, phase, targets.axis_segment)
    table = np.zeros((P, 4), int)
    use = np.zeros(P, bool)
    for i, one in enumerate(found):
        local = (*one.x_upper[:2], one.x_hinge, one.x_upper[2])
        table[i] = [entries[k] if k >= 0 else -1 for k in local]
        use[i] = True
    rows = [(one.row, one.effector, one.upper, one.hinge) for one in found]
    rows += [(0, 1, 0, 0)] * (P - len(found))
    limb_row, limb_effector, limb_upper, limb_hinge = (np.asarray(c, int) for c in zip(*rows))
    return Plan(
        free=device_array(free, bool),
        vertebrae=device_array(np.asarray(vertebrae, bool), bool),
        moves=device_array(moves, bool),
        stiffness=device_array(stiff),
        closed=device_array(closed, bool),
        point_effector=device_array(_padded(targets.point_index, P), int),
        axis_segment=device_array(_padded(targets.axis_segment, A), int),
        limb_use=device_array(use, bool),
        limb_row=device_array(limb_row, int),
        limb_effector=device_array(limb_effector, int),
        limb_upper=device_array(limb_upper, int),
        limb_hinge=device_array(limb_hinge, int),
        limb_entries=device_array(np.where(use[:, None], table, -1), int),
    )


def _padded(values: tuple[int, ...], rows: int) -> np.ndarray:
    return np.asarray(list(values) + [0] * (rows - len(values)), int)


def padded_errors(a: Attempt, ts: TargetSet) -> Attempt:
    """An attempt's errors (its targets', or a limb chain's bucket of them) padded to the
    whole tree's buckets (host; `_tree.targets_rows`)."""
    P, A = targets_rows(ts)
    n_p, n_a = len(ts.point_index), len(ts.axis_segment)

    def pad(e, n: int, rows: int) -> np.ndarray:
        e = np.asarray(e)[:n]  # its dtype kept: a float64 pad would key another conclusion
        return np.concatenate([e, np.zeros(rows - n, e.dtype)])

    errors = (pad(a.err_p, n_p, P), pad(a.err_a, n_a, A))
    return eqx.tree_at(lambda a: (a.err_p, a.err_a), a, errors)
