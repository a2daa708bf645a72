"""The whole tree's problem and a limb chain's against a phase's own (docs/design.md,
section 6, "One program per body", "Limb chains"): the same residuals, Jacobian, starts and
limb start on the phase's unknowns, nothing moving elsewhere (reference: the phase's own
layout, an independent program)."""

import equinox as eqx
import jax
import numpy as np
import pytest

import diffbody as db
from diffbody.ik._attempt import start_vector
from diffbody.ik._phases import phase_layouts, phase_plans, phase_targets_of
from diffbody.ik._plans import make_limb_plan, make_plan
from diffbody.ik._reach import constrained_targets
from diffbody.problem._problem import make_problem, stiffness_of
from diffbody.problem._targets import Target, mask_invalid, resolve_targets
from diffbody.problem._tree import padded_targets, targets_rows, tree_entries, tree_layout

CASES = {
    "palm": [Target.position("left_hand.palm", (0.35, 0.3, 1.1))],
    "wrist, a padded limb chain": [Target.position("left_wrist", (0.3, 0.4, 1.2))],
    "two hands and a direction": [
        Target.position("left_wrist", (0.3, 0.4, 1.2)),
        Target.position("right_hand.palm", (-0.3, 0.35, 1.2)),
        Target.axis_direction("right_hand", (0, 1, 0), (0, 0, -1)),
    ],
    "far, standing": [Target.position("left_hand.palm", (0.9, 0.19, 1.29))],
}


@eqx.filter_jit
def _evaluate(body, layout, init, plan, x, targets):
    """Residuals and Jacobian of a problem at x (one program: op by op takes minutes)."""
    problem = make_problem(body, layout, init, plan)
    return problem.residuals(x, targets), jax.jacfwd(problem.residuals)(x, targets)


@eqx.filter_jit
def _starts(body, layout, init, plan, targets, k):
    problem = make_problem(body, layout, init, plan)
    return problem.x0, start_vector(problem, targets, k, True)


def _phases_of(body, targets, stand=True):
    init = body.rest_pose()
    ts, _ = resolve_targets(body, targets)
    pts = constrained_targets(body, ts, targets, init, stand)
    layouts = phase_layouts(body, pts, spine=True, free_root=False, segments=None, stand=stand)
    return init, layouts, phase_targets_of(layouts, pts)


def _planned(body, layout, ts, k: int, limb: bool):
    """The layout, plan and padded targets of phase k on the whole tree's program or on a
    limb chain's, and where the phase's unknowns sit in its free vector."""
    stiffness = stiffness_of(body, layout)
    if limb:
        big, plan = make_limb_plan(body, layout, ts, k == 0, stiffness)
    else:
        big = tree_layout(body)
        plan = make_plan(body, big, layout, ts, k == 0, stiffness)
        np.testing.assert_array_equal(np.flatnonzero(plan.free), tree_entries(big, layout))
    padded, _, _ = mask_invalid(padded_targets(ts, limb))
    return big, plan, padded, np.flatnonzero(np.asarray(plan.free))


PROBLEMS = [
    ("two hands and a direction", False),
    ("far, standing", False),
    ("palm", True),
    ("wrist, a padded limb chain", True),
]


@pytest.mark.parametrize("name, limb", PROBLEMS)
def test_the_planned_problem_is_each_phase_s_problem(name, limb):
    """For every phase (the standing one included, although it runs on its own program),
    at random free vectors: the whole tree's (or, for a limb's phase, the limb chain's)
    residuals on the given target rows, the constraint rows and the pull rows of the
    phase's unknowns equal the phase's to 1e-12, the other rows are zero, and the
    Jacobian's columns of the phase's unknowns equal the phase's Jacobian while the others
    move nothing but their own pull."""
    body = db.load_body()
    init, layouts, sets = _phases_of(body, CASES[name])
    rng = np.random.default_rng(3)
    for k, (layout, ts) in enumerate(zip(layouts, sets)):
        if limb and k > 0:
            break
        big, plan, padded, entries = _planned(body, layout, ts, k, limb)
        own, _, _ = mask_invalid(ts)
        x0 = _starts(body, layout, init, None, own, np.int32(0))[0]
        X0 = _starts(body, big, init, plan, padded, np.int32(0))[0]
        x = np.asarray(x0) + 0.2 * rng.standard_normal(layout.n_free)
        X = np.asarray(X0).copy()
        X[entries] = x
        r, J = (np.asarray(a) for a in _evaluate(body, layout, init, None, x, own))
        R, JJ = (np.asarray(a) for a in _evaluate(body, big, init, plan, X, padded))
        n_p, n_a = len(ts.point_weight), len(ts.axis_weight)
        P, A = targets_rows(ts, limb)
        n_c = r.shape[0] - 3 * (n_p + n_a) - layout.n_free
        take = np.concatenate(
            [
                np.arange(3 * n_p),
                3 * P + np.arange(3 * n_a),
                3 * (P + A) + np.arange(n_c),
                3 * (P + A) + n_c + entries,
            ]
        )
        np.testing.assert_allclose(R[take], r, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(np.delete(R, take), 0.0)
        np.testing.assert_allclose(JJ[np.ix_(take, entries)], J, rtol=0, atol=1e-10)
        others = np.setdiff1d(np.arange(big.n_free), entries)
        pull_rows = 3 * (P + A) + n_c + others
        np.testing.assert_array_equal(np.delete(JJ[:, others], pull_rows, axis=0), 0.0)


@pytest.mark.parametrize("name, limb", [PROBLEMS[0], PROBLEMS[3]])
def test_the_planned_starts_are_the_phase_s_starts(name, limb):
    """The closed-form limb start (data: the plan's limbs) and the Halton starts (by rank
    among the free entries) equal the phase's own starts on its unknowns, and leave every
    other entry at the start pose's; `phase_plans` picks the limb chain where it can."""
    body = db.load_body()
    init, layouts, sets = _phases_of(body, CASES[name])
    layout, ts = layouts[0], sets[0]
    ((big, plan),) = phase_plans(body, layouts[:1], sets[:1])
    assert (plan.chain is not None) == limb
    _, _, padded, entries = _planned(body, layout, ts, 0, limb)
    own, _, _ = mask_invalid(ts)
    for k in range(4):
        a = np.asarray(_starts(body, layout, init, None, own, np.int32(k))[1])
        X0, b = (np.asarray(v) for v in _starts(body, big, init, plan, padded, np.int32(k)))
        np.testing.assert_allclose(b[entries], a, rtol=0, atol=1e-12)
        others = np.setdiff1d(np.arange(big.n_free), entries)
        np.testing.assert_array_equal(b[others], X0[others])


def test_the_tree_answers_are_the_phase_s_answers():
    """Reachable arm targets, solved on limb chains' programs (two arms, each its own:
    `_limb_groups`; one arm) and on the phase's own: both reach, and the joints agree to
    0.1 mm (a converged solve forgets rounding)."""
    from diffbody.ik import _reach

    body = db.load_body()
    for targets in (CASES["two hands and a direction"], CASES["wrist, a padded limb chain"]):
        tree = db.solve_reach(body, targets)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(_reach, "phase_plans", lambda *a: None)
            own = db.solve_reach(body, targets)
        assert int(tree.status) == int(own.status) == 0
        a, b = (np.asarray(db.forward(body, r.pose).joint_positions) for r in (tree, own))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-4)


def test_several_limbs_reach_as_each_limb_alone(monkeypatch):
    """Targets on both arms (one with its palm's direction) and a leg, the trunk held: the
    limbs' phase splits them by limb, each on its limb chain (`_limb_groups`), and every
    joint moves as the one limb's own reach moves it, to 0.1 mm, the rest not at all
    (reference: each limb's reach alone)."""
    from diffbody.ik import _phases

    body = db.load_body()
    rest = np.asarray(db.forward(body, body.rest_pose()).joint_positions)
    leg = [Target.position("left_ankle", rest[body.joint_index("left_ankle")] + [0.15, 0, 0.1])]
    hands = CASES["two hands and a direction"]
    limbs = [hands[:1], hands[1:], leg]
    found = []
    split = _phases.limb_groups
    monkeypatch.setattr(_phases, "limb_groups", lambda *a: found.append(split(*a)) or found[-1])
    joined = db.solve_reach(body, hands + leg)
    assert [len(g) for g in found] == [3]
    assert bool(np.all(joined.reached)), joined.residuals
    moved = np.zeros_like(rest)
    for targets in limbs:
        alone = db.solve_reach(body, targets)
        assert bool(np.all(alone.reached)), alone.residuals
        moved += np.asarray(db.forward(body, alone.pose).joint_positions) - rest
    got = np.asarray(db.forward(body, joined.pose).joint_positions) - rest
    np.testing.assert_allclose(got, moved, rtol=0, atol=1e-4)
