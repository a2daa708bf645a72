"""Reach (inverse kinematics): targets reached, limits exact, bad input clear."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from limb_poses import random_limb_angles

import diffbody as db
from diffbody.ik._post_projection import project_to_standard


@pytest.fixture(scope="module")
def palm0(male50):
    fk = db.forward(male50, male50.rest_pose())
    return np.asarray(fk.feature_points[male50.feature_index("left_hand.palm")])


def _check_limits(body, pose):
    assert float(jnp.max(db.stop_violation(body, pose))) <= 1e-9
    assert np.all(np.isfinite(np.asarray(pose.angles)))


@pytest.mark.parametrize("offset", [[0.05, 0.0, 0.05], [0.25, 0.1, 0.35]])
def test_reachable_targets_are_reached_within_the_limits(male50, palm0, offset):
    target = palm0 + np.asarray(offset)
    out = db.solve_reach(male50, [db.Target.position("left_hand.palm", target)])
    assert bool(out.reached[0]) and float(out.residuals[0]) < 1e-3
    _check_limits(male50, out.pose)
    fk = db.forward(male50, out.pose)
    got = np.asarray(fk.feature_points[male50.feature_index("left_hand.palm")])
    np.testing.assert_allclose(np.linalg.norm(got - target), out.residuals[0], atol=1e-12)


def test_a_low_reach_bends_the_spine(male50, palm0):
    target = palm0 + np.asarray([0.35, 0.0, -0.2])  # low in front: needs the trunk
    out = db.solve_reach(male50, [db.Target.position("left_hand.palm", target)])
    assert bool(out.reached[0])
    _check_limits(male50, out.pose)
    rest_flexion = float(male50.spine.rest.sum(0)[0])
    assert float(out.pose.spine_target[0]) > rest_flexion + 0.2  # the trunk bends forward
    # The post-projection keeps every joint, the other arm's too (regression: it moved the
    # right fingertip by 72 mm, the vertebrae's twists reset under the spine target's).
    raw = db.solve_reach(
        male50, [db.Target.position("left_hand.palm", target)], standard_orientation=False
    )
    np.testing.assert_allclose(out.pose.spine_target, raw.pose.spine_target, atol=1e-12)
    j_raw = db.forward(male50, raw.pose).joint_positions
    np.testing.assert_allclose(db.forward(male50, out.pose).joint_positions, j_raw, atol=1e-8)


def test_the_post_projection_of_a_bent_spine_keeps_every_joint(male50):
    """`project_to_standard` of a pose with a spine target and a twisted right forearm (not
    kept): the twist goes back to the standard orientation, the spine target stays, and no
    joint moves (the segments hanging from the vertebrae projected from the frames the
    target gives them)."""
    rest = male50.rest_pose()
    forearm = male50.segment_index("right_forearm")
    target = male50.spine.rest.sum(0) + jnp.asarray([0.4, 0.25, -0.2])
    pose = db.Pose(rest.position, rest.angles.at[forearm, 2].set(0.6), spine_target=target)
    keep = np.zeros(male50.n_segments, bool)
    keep[[male50.segment_index(s) for s in ARM]] = True
    out = project_to_standard(male50, pose, keep)
    assert abs(float(out.angles[forearm, 2])) < 1e-9
    np.testing.assert_array_equal(out.spine_target, target)
    before, after = db.forward(male50, pose), db.forward(male50, out)
    np.testing.assert_allclose(after.joint_positions, before.joint_positions, atol=1e-9)


def test_unreachable_target_gives_the_closest_reach(male50, palm0):
    out = db.solve_reach(male50, [db.Target.position("left_hand.palm", palm0 + [3.0, 0, 0])])
    assert not bool(out.reached[0])
    assert 1.5 < float(out.residuals[0]) < 3.0 and np.isfinite(float(out.residuals[0]))
    _check_limits(male50, out.pose)


def test_position_and_palm_orientation_together(male50, palm0):
    targets = [
        db.Target.position("left_hand.palm", palm0 + [0.3, 0.05, 0.3]),
        db.Target.axis_direction("left_hand", [0, 1, 0], [0, 0, -1]),  # palm faces down
    ]
    out = db.solve_reach(male50, targets)
    assert np.all(np.asarray(out.reached)), out.residuals
    _check_limits(male50, out.pose)


def test_bad_targets_are_rejected_clearly(male50):
    with pytest.raises(ValueError, match="non-finite"):
        db.solve_reach(male50, [db.Target.position("left_hand.palm", [np.nan, 0, 1])])
    with pytest.raises(KeyError, match="left_hand.palm"):
        db.solve_reach(male50, [db.Target.position("left_hand.plam", [0, 0, 1])])
    with pytest.raises(ValueError, match="3 numbers"):
        db.solve_reach(male50, [db.Target.position("left_wrist", [0, 1])])


def test_implicit_gradient_of_the_reach_with_respect_to_the_target(male50, palm0):
    """Reverse mode through the solve (the implicit function theorem at the optimum): where a
    target is reached, the reached point follows the target one to one, so the Jacobian is
    I, up to the light pull toward init (1e-6 per unit, here 1.1e-5 off I: the stretched
    arm's smallest singular values are ~0.1).

    The hand starts flexed by 0.2 rad: the closed-form limb start leaves it where init has
    it, and a segment exactly at its socket's pole (the hanging hand of the standard
    position) has seed 000 angles (theta, phi) whose derivatives lose a direction there
    (checked finite below)."""
    palm = male50.feature_index("left_hand.palm")
    hand = male50.segment_index("left_hand")
    rest = male50.rest_pose()
    init = db.Pose(position=rest.position, angles=rest.angles.at[hand, 1].add(-0.2))

    def reached(t, init):
        target = [db.Target.position("left_hand.palm", t)]
        out = db.solve_reach(male50, target, init=init, segments=ARM, starts=1)
        return db.forward(male50, out.pose).feature_points[palm]

    # One compiled derivative (the solve, its implicit derivative and their transpose in one
    # XLA program) instead of hundreds of small ones run op by op.
    jac = jax.jit(jax.jacrev(reached))
    J = jac(jnp.asarray(palm0 + [0.25, 0.1, 0.35]), init)
    np.testing.assert_allclose(J, np.eye(3), atol=1e-4)
    # Out of reach the arm ends straight, a singular posture: the derivatives stay finite
    # (same shapes: the compiled derivative is reused).
    J_far = jac(jnp.asarray(palm0 + [2.0, 0.0, 0.0]), init)
    assert np.all(np.isfinite(J_far))
    # With the hand at its pole (init the standard position), finite too.
    assert np.all(np.isfinite(jac(jnp.asarray(palm0 + [0.25, 0.1, 0.35]), rest)))


def test_solve_reach_traces_under_jit_with_a_closed_over_body(male50, palm0):
    """Regression: the effectors' indices were arrays, traced under jax.jit, and the phases'
    layouts (static structure) could not be read off them. Under jit the solve runs its
    starts side by side and reaches the target; a target that is not finite cannot be
    refused there (its value is unknown when traced): it takes no part, INVALID_TARGET
    (README, "Errors")."""

    @jax.jit
    def reach(t):
        out = db.solve_reach(male50, [db.Target.position("left_hand.palm", t)], **ARM_ONLY)
        palm = db.forward(male50, out.pose).feature_points[male50.feature_index("left_hand.palm")]
        return out, palm

    target = palm0 + np.asarray([0.25, 0.1, 0.35])
    out, palm = reach(jnp.asarray(target))
    assert int(out.status) == db.ReachStatus.SUCCESS
    assert bool(out.reached[0]) and bool(out.valid[0]) and float(out.residuals[0]) < 1e-3
    np.testing.assert_allclose(np.linalg.norm(palm - target), out.residuals[0], atol=1e-12)
    _check_limits(male50, out.pose)
    out, _ = reach(jnp.asarray([np.nan, 0.2, 1.0]))  # the same compiled solve
    assert int(out.status) == db.ReachStatus.INVALID_TARGET
    assert not bool(out.valid[0]) and not bool(out.reached[0]) and float(out.residuals[0]) == 0
    assert np.all(np.isfinite(np.asarray(out.pose.angles)))


def test_a_non_finite_batch_row_is_an_invalid_target(male50):
    """`solve_reach_batch` flags a row with a NaN or infinite coordinate instead of raising
    (README, "Errors"): valid and reached False, residual 0, status INVALID_TARGET; the rows
    around it are solved. (The batch shape of tests/ik/test_batch.py: one compiled solve.)"""
    from diffbody.ik._reach_batch import solve_reach_batch

    rows = np.array([[0.3, 0.2, 1.0], [0.3, np.inf, 1.0], [0.15, 0.3, 0.85]])
    out = solve_reach_batch(
        male50, ["left_hand.palm"], rows, chunk_size=2, progress=False, **ARM_ONLY
    )
    success, invalid = db.ReachStatus.SUCCESS, db.ReachStatus.INVALID_TARGET
    np.testing.assert_array_equal(out.status, [success, invalid, success])
    np.testing.assert_array_equal(out.valid[:, 0], [True, False, True])
    np.testing.assert_array_equal(out.reached[:, 0], [True, False, True])
    assert out.residuals[1, 0] == 0 and np.all(out.residuals[[0, 2], 0] < 1e-3)
    assert np.all(np.isfinite(out.pose.angles))


ARM = ("left_upper_arm", "left_forearm", "left_hand")
ARM_ONLY = dict(segments=ARM, starts=1)
TIGHT = dict(tol_position=1e-10, tol_angle=1e-10)


@pytest.fixture(scope="module")
def arm_batch(male50):
    """1,000 palm targets made by FK of random in-limit arm poses, then 1,000 random points
    of a 2 m box around the shoulder (many beyond reach), solved by the arm (one compile)."""
    rng = np.random.default_rng(7)
    palm = male50.feature_index("left_hand.palm")
    rest = male50.rest_position

    @jax.jit
    @jax.vmap
    def palm_of(angles):
        return db.forward(male50, db.Pose(rest, angles)).feature_points[palm]

    reachable = np.asarray(palm_of(random_limb_angles(male50, ARM, rng, 1000)))
    shoulder = np.asarray(db.forward(male50, male50.rest_pose()).joint_positions)[
        male50.joint_index("left_shoulder")
    ]
    anywhere = shoulder + rng.uniform(-1.0, 1.0, (1000, 3))
    xyz = np.concatenate([reachable, anywhere])
    out = db.solve_reach_batch(
        male50, ["left_hand.palm"], xyz, segments=ARM, chunk_size=1000, progress=False
    )
    return out, np.linalg.norm(anywhere - shoulder, axis=-1), xyz


def test_thousands_of_reach_results_hold_every_limit(male50, arm_batch):
    out, *_ = arm_batch
    violation = jax.vmap(lambda a: db.stop_violation(male50, db.Pose(male50.rest_position, a)))(
        jnp.asarray(out.pose.angles)
    )
    assert float(jnp.max(violation)) <= 1e-9
    assert np.all(np.isfinite(out.residuals)) and np.all(np.isfinite(out.pose.angles))


def test_fk_generated_targets_are_reached(arm_batch):
    """At least 99.5 % within 1 mm with the defaults (up to 8 starts of 30 steps)."""
    out, *_ = arm_batch
    rate = out.reached[:1000, 0].mean()
    assert rate >= 0.995, rate
    assert np.median(out.residuals[:1000, 0]) < 1e-4  # 30 steps: tens of micrometres
    # The solver stops once the target is within a hundredth of the tolerance (10 um).
    assert np.median(out.steps[:1000]) < 20
    assert np.median(out.residuals[:1000, 0]) < 2e-5


def test_the_second_pass_gives_what_solve_reach_gives(male50, arm_batch):
    """Rows the first start missed (reached later, or never) come out of the batch's second
    pass as `solve_reach` gives them, trying the same starts in the same order."""
    out, _, xyz = arm_batch
    later = np.flatnonzero(out.reached[:, 0] & (out.steps > 30))[:2]
    never = np.flatnonzero(~out.reached[:, 0])[:1]
    for i in np.concatenate([later, never]):
        one = db.solve_reach(male50, [db.Target.position("left_hand.palm", xyz[i])], segments=ARM)
        assert bool(one.reached[0]) == bool(out.reached[i, 0]) and int(one.steps) == out.steps[i]
        np.testing.assert_allclose(np.asarray(one.residuals), out.residuals[i], atol=1e-9)


def test_targets_beyond_the_arm_are_flagged(male50, arm_batch):
    """A target farther from the shoulder than the whole arm (upper arm + forearm + the
    palm's distance from the wrist) cannot be reached; its residual is at least the gap."""
    out, distance, _ = arm_batch
    arm = float(sum(male50.lengths[male50.segment_index(s)] for s in ARM))
    beyond = distance > arm
    assert beyond.sum() > 100
    assert not out.reached[1000:, 0][beyond].any()
    assert np.all(out.residuals[1000:, 0][beyond] >= distance[beyond] - arm - 1e-9)


def test_implicit_gradient_with_respect_to_a_dimension_matches_finite_differences(male50):
    """How the solved arm changes when the forearm grows: jax.jacfwd through the solve (the
    implicit function theorem at the optimum) against central differences of two solves.
    The targets (palm position and the hand's full frame: 9 residuals, 7 unknowns) fix the
    solution. Tight tolerances: the solver stops once every target is within a hundredth of
    its tolerance, and the differences need solves converged far below their step."""
    import equinox as eqx

    true = db.Pose(
        male50.rest_position, random_limb_angles(male50, ARM, np.random.default_rng(3), 1)[0]
    )
    hand, palm = male50.segment_index("left_hand"), male50.feature_index("left_hand.palm")
    fk = db.forward(male50, true)
    targets = [db.Target.position("left_hand.palm", np.asarray(fk.feature_points[palm]))]
    targets += db.Target.frame("left_hand", np.asarray(fk.R_world_twisted[hand]))
    idx = np.asarray([male50.segment_index(s) for s in ARM])
    forearm = male50.segment_index("left_forearm")

    def solved_swing(dL):
        body = eqx.tree_at(lambda b: b.lengths, male50, male50.lengths.at[forearm].add(dL))
        out = db.solve_reach(
            body, targets, init=true, segments=ARM, starts=1, max_steps=200, **TIGHT
        )
        swing = db.swing_vector(body, out.pose.angles)[idx]
        return swing, swing

    # One compiled program gives the solved swing (the aux output: the solve's own answer,
    # which the implicit derivative passes through unchanged) and its derivative, so the
    # finite differences' two solves reuse the derivative's compiled solve.
    swing_and_derivative = jax.jit(jax.jacfwd(solved_swing, has_aux=True))
    J, _ = swing_and_derivative(0.0)
    h = 1e-4
    fd = (swing_and_derivative(h)[1] - swing_and_derivative(-h)[1]) / (2 * h)
    assert float(jnp.max(jnp.abs(J))) > 0.1  # the answer moves
    np.testing.assert_allclose(J, fd, atol=2e-3)


def test_the_standard_orientation_is_restored_after_the_solve(male50):
    """A wrist target moves the upper arm and forearm; no target depends on the forearm's
    twist, so the post-projection resets it to the standard orientation, keeping the
    joints. The upper arm keeps its twist: it carries the elbow's hinge plane."""
    target = [db.Target.position("left_wrist", [0.25, 0.35, 1.05])]
    upper, forearm = (male50.segment_index(s) for s in ("left_upper_arm", "left_forearm"))
    rest = male50.rest_pose()
    init = db.Pose(rest.position, rest.angles.at[forearm, 2].set(0.5))  # a pronated start
    raw = db.solve_reach(
        male50, target, init=init, segments=ARM, starts=1, standard_orientation=False
    )
    out = db.solve_reach(male50, target, init=init, segments=ARM, starts=1)
    assert bool(out.reached[0])
    _check_limits(male50, out.pose)
    j_raw = db.forward(male50, raw.pose).joint_positions
    j_out = db.forward(male50, out.pose).joint_positions
    np.testing.assert_allclose(j_out, j_raw, atol=1e-8)  # float64 rounding of a re-pose
    assert abs(float(raw.pose.angles[forearm, 2])) > 0.1
    assert float(out.pose.angles[forearm, 2]) == 0.0
    np.testing.assert_allclose(out.pose.angles[upper], raw.pose.angles[upper], atol=1e-12)


def _spine_sum(body, pose):
    if pose.spine_target is not None:
        return np.asarray(pose.spine_target)
    return np.asarray(db.spine_angles(body, body.spine, pose).sum(0))


def test_arm_reachable_targets_leave_the_trunk_where_it_was(male50):
    """Palm positions of random in-limit arm poses (clavicle and all else at rest) are
    reached with the default unknowns (the whole chain, the spine included), and the arm
    reaches them alone: each spine sum within 2 degrees of init's, every segment off the
    left arm and clavicle within 2 degrees of its swing at rest."""
    rest = male50.rest_pose()
    palm = male50.feature_index("left_hand.palm")
    angles = random_limb_angles(male50, ARM, np.random.default_rng(11), 6)
    arm = {male50.segment_index(s) for s in ARM + ("left_clavicle",)}
    others = np.asarray([i for i in range(male50.n_segments) if i not in arm])
    w_rest = np.asarray(db.swing_vector(male50, rest.angles))[others]
    for a in angles:
        target = np.asarray(db.forward(male50, db.Pose(rest.position, a)).feature_points[palm])
        out = db.solve_reach(male50, [db.Target.position("left_hand.palm", target)])
        assert int(out.status) == db.ReachStatus.SUCCESS, out.residuals
        moved = np.degrees(np.abs(_spine_sum(male50, out.pose) - _spine_sum(male50, rest)))
        assert np.all(moved <= 2.0), moved
        w = np.asarray(db.swing_vector(male50, out.pose.angles))[others]
        assert np.degrees(np.max(np.abs(w - w_rest))) <= 2.0


def test_the_reach_ladder_bends_the_spine_only_beyond_the_arm(male50):
    """Targets ever farther in front of the shoulder: the spine stays at rest while the arm
    reaches, then bends forward, more the farther the target (docs/design.md, section 6)."""
    rest = male50.rest_pose()
    shoulder = np.asarray(db.forward(male50, rest).joint_positions)[
        male50.joint_index("left_shoulder")
    ]
    flexion = []
    for d in (0.3, 0.5, 0.7, 0.8):
        target = shoulder + [d, 0.0, -0.1]
        palm = [db.Target.position("left_hand.palm", target)]
        out = db.solve_reach(male50, palm, standing=False)  # the pelvis fixed in space
        assert bool(out.reached[0]), (d, out.residuals)
        _check_limits(male50, out.pose)
        flexion.append(float(_spine_sum(male50, out.pose)[0] - _spine_sum(male50, rest)[0]))
    assert abs(flexion[0]) < 1e-9 and abs(flexion[1]) < 1e-9  # the arm alone
    assert flexion[3] > flexion[2] >= 0.0 and flexion[3] > np.radians(5)  # then the trunk


def test_status_names_what_happened(male50, palm0):
    """SUCCESS when reached; UNREACHABLE (and `beyond`) for a target past every chain."""
    far = db.solve_reach(male50, [db.Target.position("left_hand.palm", palm0 + [3.0, 0, 0])])
    assert int(far.status) == db.ReachStatus.UNREACHABLE and bool(far.beyond[0])
    huge = db.solve_reach(male50, [db.Target.position("left_hand.palm", [1e30, 0.0, 1.0])])
    assert not bool(huge.reached[0]) and np.isfinite(float(huge.residuals[0]))
    assert bool(huge.valid[0]) and int(huge.status) == db.ReachStatus.UNREACHABLE
    assert np.all(np.isfinite(np.asarray(huge.pose.angles)))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(starts=0), "starts"),
        (dict(max_steps=0), "max_steps"),
        (dict(tol_position=-1.0), "tol_position"),
    ],
)
def test_bad_settings_name_the_argument(male50, kwargs, name):
    with pytest.raises(ValueError, match=name):
        db.solve_reach(male50, [db.Target.position("left_wrist", [0.2, 0.3, 1.0])], **kwargs)


@pytest.mark.parametrize("weight", [-1.0, np.nan, np.inf])
def test_bad_weights_are_rejected(weight):
    with pytest.raises(ValueError, match="weight"):
        db.Target.position("left_wrist", [0.2, 0.3, 1.0], weight=weight)


def test_a_zero_axis_is_rejected():
    with pytest.raises(ValueError, match="axis"):
        db.Target.axis_direction("left_hand", [0, 0, 0], [0, 0, -1])
    with pytest.raises(ValueError, match="direction"):
        db.Target.axis_direction("left_hand", [0, 1, 0], [0, 0, 0])
