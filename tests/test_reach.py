"""Reach (inverse kinematics): targets reached, limits exact, bad input clear."""

import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db


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
    """Differentiating through the solve (optimistix's implicit adjoint): where a target is
    reached, the reached point follows the target one to one, so the Jacobian is I."""
    import jax

    palm = male50.feature_index("left_hand.palm")

    def reached(t):
        out = db.solve_reach(male50, [db.Target.position("left_hand.palm", t)])
        return db.forward(male50, out.pose).feature_points[palm]

    J = jax.jacrev(reached)(jnp.asarray(palm0 + [0.25, 0.1, 0.35]))
    np.testing.assert_allclose(J, np.eye(3), atol=1e-4)
