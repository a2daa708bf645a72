"""A phase's plan on the whole tree (host, docs/design.md, section 6, "One program per
body"): which of the tree's unknowns the phase moves, its limbs and effectors, as the data
of the one compiled round (`_tree`)."""

import numpy as np

from .._body import Body
from .._device_arrays import device_array
from ._limb_start import limbs
from ._targets import TargetSet
from ._tree import Plan, targets_rows, tree_entries
from ._unknowns import Layout


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
    free = np.zeros(tree.n_free, bool)
    free[entries] = True
    stiff = np.ones(tree.n_free)
    stiff[entries] = stiffness
    spine_rows = set(phase.spine_rows)
    vertebrae = np.asarray([r in spine_rows for r in tree.spine_rows], bool)
    moves = np.zeros(body.n_segments, bool)
    segs = phase.chain.segments
    moves[[segs[k] for k in set(phase.swing_x + phase.swing_y + phase.twist)]] = True
    P, A = targets_rows(targets)
    found = limbs(body, phase, targets.axis_segment)
    table = np.zeros((P, 4), int)
    use = np.zeros(P, bool)
    for i, limb in enumerate(found):
        local = (*limb.x_upper[:2], limb.x_hinge, limb.x_upper[2])
        table[i] = [entries[k] if k >= 0 else -1 for k in local]
        use[i] = True
    rows = [(limb.row, limb.effector, limb.upper, limb.hinge) for limb in found]
    rows += [(0, 1, 0, 0)] * (P - len(found))
    limb_row, limb_effector, limb_upper, limb_hinge = (np.asarray(c, int) for c in zip(*rows))
    return Plan(
        free=device_array(free, bool),
        vertebrae=device_array(vertebrae, bool),
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
