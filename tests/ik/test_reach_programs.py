"""What a reach compiles: settings that are data share one program (docs/design.md,
section 6, "Programs")."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import compiled_names, counted_compiles

import diffbody as db
from diffbody import _programs
from diffbody.ik._attempt import ROUND_STEPS, Settings, solve_free
from diffbody.ik._phases import phase_layouts
from diffbody.ik._reach import constrained_targets
from diffbody.problem._problem import make_problem
from diffbody.problem._targets import Target, resolve_targets


def test_the_step_budget_is_data(male50):
    """Another `max_steps` (other round caps: 10 + 10 + 5 after 10 + 10 + 10) and another
    reachable target compile nothing new."""
    first = db.solve_reach(male50, [Target.position("left_hand.palm", (0.35, 0.3, 1.1))])
    assert int(first.status) == 0
    with counted_compiles() as seen:
        out = db.solve_reach(
            male50, [Target.position("left_hand.palm", (0.3, 0.35, 1.0))], max_steps=25
        )
    assert int(out.status) == 0
    assert seen == []


@pytest.mark.parametrize("cap", [1, 2, 4, 7])
def test_a_step_cap_given_as_data_stops_where_a_static_one_does(male50, cap):
    """`solve_free` with `cap` steps inside a loop bounded by `ROUND_STEPS` returns what
    optimistix's own `max_steps = cap` returns (the reference): the same free vector, steps
    and verdict, on a target that needs more steps than the cap."""
    rest = male50.rest_pose()
    target = Target.position("left_hand.palm", (-0.3, 0.4, 1.2))
    ts, _ = resolve_targets(male50, [target])
    phase_targets = constrained_targets(male50, ts, [target], rest, False)
    layout = phase_layouts(
        male50, phase_targets, spine=True, free_root=False, segments=None, stand=False
    )[0]
    settings = Settings(jnp.asarray(1e-3), jnp.asarray(np.deg2rad(1.0)), True)
    start = (jnp.zeros(layout.n_free), jnp.asarray(0), jnp.asarray(True))

    # Compiled (op by op, each of its hundreds of operations is a program of its own).
    @eqx.filter_jit
    def solve(max_steps, cap=None):
        problem = make_problem(male50, layout, rest)
        return solve_free(problem, phase_targets[0], *start, max_steps, settings, cap)

    x_static, steps_static, done_static = solve(cap)
    x_data, steps_data, done_data = solve(ROUND_STEPS, jnp.asarray(cap))
    assert int(steps_static) == cap and not bool(done_static)
    assert int(steps_data) == cap and not bool(done_data)
    np.testing.assert_allclose(x_data, x_static, rtol=0, atol=1e-6)


def test_a_standing_solve_compiles_each_phase_once(male50, monkeypatch):
    """A far reach with the right hand (no other test's effector): the limbs' round and the
    trunk's, each compiled once, although every round after the first starts from the last
    one's answer (a device array, where the first round's is a host array); and `forward`,
    compiled for the rest pose, not again for the trunk's start (a solve's answer)."""
    # As a new process: whatever an earlier test in this worker compiled or loaded, gone.
    jax.clear_caches()
    monkeypatch.setattr(_programs, "_LOADED", {})
    monkeypatch.setattr(_programs, "_SEEN", {})
    db.forward(male50, male50.rest_pose())
    with compiled_names() as names:
        out = db.solve_reach(male50, [Target.position("right_hand.palm", (0.85, -0.35, 0.75))])
    assert out.pose.spine_target is not None  # the trunk joined
    assert names.count("attempt_round") == 2, names
    assert "_forward" not in names, names


def test_after_a_standing_reach_the_conclusion_compiles_no_more(male50, monkeypatch):
    """Regressions: the conclusion of a limbs' answer (no spine target) compiled a program
    of its own (1.3 s) beside the one of a standing answer (a spine target), and so did
    every other constraint set (a segment subset's: none; 1.1 s), and an answer whose
    errors were padded in float64. Whether the spine is bent is data, and the violations
    are reckoned after the conclusion: after a far standing reach alone, in a fresh state,
    an arm reach and a segment subset's compile nothing, and a reach avoiding contact
    compiles its round and its violations, not a conclusion."""
    jax.clear_caches()
    monkeypatch.setattr(_programs, "_LOADED", {})
    monkeypatch.setattr(_programs, "_SEEN", {})
    far = db.solve_reach(male50, [Target.position("left_hand.palm", (0.3, 0.9, 0.8))])
    assert far.pose.spine_target is not None  # the trunk joined
    arm = ["left_clavicle", "left_upper_arm", "left_forearm", "left_hand"]
    with counted_compiles() as seen:
        out = db.solve_reach(male50, [Target.position("right_wrist", (-0.25, 0.3, 1.15))])
        sub = db.solve_reach(male50, [Target.position("left_wrist", (0.3, 0.3, 1.2))], segments=arm)
    assert seen == []
    assert int(out.status) == 0 and out.pose.spine_target is None
    assert int(sub.status) == 0 and sub.constraint_names == () and sub.violation.shape == (0,)
    spheres = ["left_upper_arm", "left_forearm", "left_hand"]
    given = [Target.position("left_hand.palm", (0.3, 0.3, 1.0)), Target.no_contact(spheres)]
    with compiled_names() as names:
        avoid = db.solve_reach(male50, given)
    assert "_conclude" not in names, names
    assert int(avoid.status) == 0 and avoid.constraint_names == (
        "no_contact",
        "on_floor",
        "balance",
    )


def test_a_body_without_a_spine_database_concludes_without_a_stand_in(tmp_path):
    """A regression: the conclusion's stand-in spine target bent a spine the body does not
    have (AttributeError). A body without a spine database (`bodies.MINI`) reaches its
    wrist target with no spine target in its answer."""
    from bodies import mini_doc, write

    mini = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    assert mini.spine is None
    wrist = np.asarray(db.forward(mini, mini.rest_pose()).joint_positions)[-1]
    target = Target.position("left_wrist", wrist + [0.05, 0.05, -0.05])
    out = db.solve_reach(mini, [target])
    assert int(out.status) == 0 and out.pose.spine_target is None
    assert float(out.residuals[0]) < 1e-3


def test_the_reported_violations_are_the_pose_s(male50):
    """The violations reckoned after the conclusion, on the host (`forward`'s program and
    one per constraint set), are those of the answer's pose reckoned inside one traced
    program (reference: `pose_violations` under `jax.jit`), and the status follows them;
    on a far standing reach whose pose carries its spine target."""
    from diffbody.problem._constraints import pose_violations

    target = Target.position("left_hand.palm", (0.9, 0.193, 1.1))
    out = db.solve_reach(male50, [target])
    assert out.pose.spine_target is not None and len(out.constraint_names) == 3
    ts, _ = resolve_targets(male50, [target])
    c = constrained_targets(male50, ts, [], male50.rest_pose(), True)[-1].constraints
    traced = jax.jit(lambda pose: pose_violations(male50, pose, c))(out.pose)
    np.testing.assert_allclose(out.violation, traced, rtol=0, atol=1e-6)
    assert (int(out.status) == 0) == bool(np.all(out.reached) and np.all(out.violation <= 1e-3))


def test_a_limbs_answer_keeps_the_vertebrae_of_its_start(male50):
    """The conclusion's stand-in spine target (zero, where the spine is not bent) moves
    nothing: from a start with a bent spine, an arm reach keeps every vertebra's angles
    exactly, has no spine target, and its palm is on the target (reference: the angles of
    the start)."""
    spine, bend = male50.spine, np.deg2rad([15.0, 5.0, 8.0])
    init = db.bend_pose(male50, spine, male50.rest_pose(), bend, initiator=spine.initiator)[0]
    target = (0.3, 0.35, 1.05)
    out = db.solve_reach(male50, [Target.position("left_hand.palm", target)], init=init)
    assert int(out.status) == 0 and out.pose.spine_target is None
    vertebrae = [male50.segment_index(name) for name in male50.spine.segment_names]
    np.testing.assert_array_equal(
        np.asarray(out.pose.angles)[vertebrae], np.asarray(init.angles)[vertebrae]
    )
    fk = db.forward(male50, out.pose)
    palm = fk.feature_points[male50.feature_names.index("left_hand.palm")]
    assert np.linalg.norm(np.asarray(palm) - target) < 1e-3


def test_new_effectors_subsets_and_row_counts_compile_nothing(male50):
    """One program per body and bucket for the limbs' phase: a limb chain's (one arm or leg,
    `_tree.limb_layout`; several limbs, each on its own: `_limb_groups`). After a reach of
    each kind (an arm's, a far reach where the trunk joins standing, a segment subset, a
    palm with its direction), another arm's or a leg's reach, another subset, two targets on
    two limbs (a regression: they compiled the whole tree's round, 4.7 s) and another palm
    with its direction compile nothing new, and reach. A far reach with another effector
    compiles its standing round only (the standing phase keeps a program per layout:
    `_phases.phase_plans`)."""
    arm = ["left_clavicle", "left_upper_arm", "left_forearm", "left_hand"]
    right_arm = [name.replace("left", "right") for name in arm]
    palm_down = Target.axis_direction("right_hand", (0, 1, 0), (0, 0, -1))
    palm_up = Target.axis_direction("left_hand", (0, 1, 0), (0, 0, 1))
    warm = [
        db.solve_reach(male50, [Target.position("left_hand.palm", (0.35, 0.3, 1.1))]),
        db.solve_reach(male50, [Target.position("left_hand.palm", (0.3, 0.9, 0.8))]),
        db.solve_reach(male50, [Target.position("left_wrist", (0.3, 0.3, 1.2))], segments=arm),
        db.solve_reach(male50, [Target.position("left_hand.palm", (0.3, 0.35, 1.2)), palm_up]),
    ]
    assert warm[1].pose.spine_target is not None  # the trunk joined
    ankle = np.asarray(db.forward(male50, male50.rest_pose()).joint_positions)[
        male50.joint_names.index("left_ankle")
    ]
    with counted_compiles() as seen:
        outs = [
            db.solve_reach(male50, [Target.position("right_wrist", (-0.25, 0.3, 1.15))]),
            db.solve_reach(male50, [Target.position("left_ankle", ankle + [0.15, 0.0, 0.1])]),
            db.solve_reach(
                male50,
                [
                    Target.position("left_wrist", (0.3, 0.4, 1.2)),
                    Target.position("right_hand.palm", (-0.3, 0.3, 1.1)),
                ],
            ),
            db.solve_reach(
                male50, [Target.position("right_hand.palm", (-0.3, 0.35, 1.2)), palm_down]
            ),
            db.solve_reach(
                male50, [Target.position("right_wrist", (-0.25, 0.3, 1.15))], segments=right_arm
            ),
        ]
    assert seen == []
    for out in warm + outs:
        # The raised foot leaves the floor standing's constraints name: reached, not SUCCESS.
        assert bool(np.all(out.reached)), out.residuals
    assert all(out.pose.spine_target is None for out in outs)  # the limbs alone
    with compiled_names() as names:
        far = db.solve_reach(male50, [Target.position("left_wrist", (0.3, 0.8, 0.8))])
    assert far.pose.spine_target is not None and int(far.status) == 0
    # Of the solve's programs: the standing round alone (a first export also logs its own
    # tracing and a few tiny conversions).
    solve = [n for n in names if n in ("attempt_round", "_conclude", "_forward")]
    assert solve == ["attempt_round"], names
