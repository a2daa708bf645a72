"""Local coordinate systems (seed 001) and the analytic posture from joint positions."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bodies import random_pose

import diffbody as db


@pytest.fixture(scope="module")
def round_trip(male50):
    """Joint positions -> pose -> joint positions, batched and compiled once."""

    def one(pose, deviation):
        p = db.forward(male50, pose).joint_positions
        back = db.pose_from_joint_positions(male50, p, deviation)
        return p, back, db.forward(male50, back).joint_positions

    return jax.jit(jax.vmap(one))


def _batch(poses):
    return jax.tree.map(lambda *x: jnp.stack(x), *poses)


@pytest.mark.parametrize("within_limits", [True, False])
def test_pose_from_joint_positions_reproduces_them(male50, round_trip, within_limits):
    rng = np.random.default_rng(10 + within_limits)
    poses = _batch([random_pose(male50, rng, within_limits=within_limits) for _ in range(24)])
    deviation = jnp.asarray(rng.uniform(-0.5, 0.5, (24, male50.n_segments)))
    p, back, p2 = round_trip(poses, deviation)
    assert float(jnp.max(jnp.abs(p2 - p))) < 1e-9
    # Twists are the standard orientation plus the requested deviation (not the whole body's
    # stance, which the positions fix).
    np.testing.assert_allclose(back.angles[:, 1:, 2], deviation[:, 1:], atol=1e-12)


def test_standard_position_is_recovered(male50, round_trip):
    rest = male50.rest_pose()
    _, back, _ = round_trip(_batch([rest]), jnp.zeros((1, male50.n_segments)))
    fk = db.forward(male50, jax.tree.map(lambda x: x[0], back))
    np.testing.assert_allclose(fk.R_world_twisted, male50.R_socket_rest, atol=1e-9)


def test_apply_standard_orientation_keeps_joints_and_resets_twists(male50):
    pose = random_pose(male50, np.random.default_rng(12))
    out = db.apply_standard_orientation(male50, pose)
    np.testing.assert_allclose(
        db.forward(male50, out).joint_positions, db.forward(male50, pose).joint_positions, atol=1e-9
    )
    np.testing.assert_allclose(out.angles[1:, 2], 0.0)
    # Idempotent: the projection of a projection is itself.
    again = db.apply_standard_orientation(male50, out)
    np.testing.assert_allclose(np.angle(np.exp(1j * (again.angles - out.angles))), 0.0, atol=1e-9)


def test_pose_from_positions_for_a_rerooted_body(male50):
    planted = male50.with_root("left_toe_tip")
    pose = random_pose(planted, np.random.default_rng(13))
    p = db.forward(planted, pose).joint_positions
    back = db.pose_from_joint_positions(planted, p)
    np.testing.assert_allclose(db.forward(planted, back).joint_positions, p, atol=1e-9)


def test_posture_gradients_finite_at_the_standard_position(male50):
    p = db.forward(male50, male50.rest_pose()).joint_positions
    # One program (op by op, the walk's scan compiles a program per operation).
    g = jax.jit(jax.grad(lambda x: jnp.sum(db.pose_from_joint_positions(male50, x).angles ** 2)))(p)
    assert np.all(np.isfinite(g))


# --- seed 001's local coordinate systems --------------------------------------------------


def test_local_frame_is_the_seed_recipe():
    bone, ref = jnp.array([0.3, -0.2, 0.9]), jnp.array([1.0, 0.0, 0.0])
    R = np.asarray(db.local_frame(bone, ref))
    x = np.asarray(bone) / np.linalg.norm(bone)
    y = np.cross(x, ref)
    y /= np.linalg.norm(y)
    np.testing.assert_allclose(R, np.stack([x, y, np.cross(x, y)], -1), atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)


def test_fixed_reference_flips_but_smooth_reference_does_not():
    """The seed's caveat: a bone passing by its reference axis spins the frame. The
    transported reference keeps it still."""
    ref = jnp.array([0.0, 0.0, 1.0])
    rest_bone = jnp.array([1.0, 0.0, 0.0])
    rest_ref = jnp.array([0.0, 0.0, 1.0])
    before = jnp.array([1e-4, 0.0, 1.0])
    after = jnp.array([-1e-4, 0.0, 1.0])  # a tiny step across the reference axis
    jump_seed = np.abs(np.asarray(db.local_frame(before, ref) - db.local_frame(after, ref))).max()
    smooth = lambda b: db.local_frame(b, db.smooth_reference(b, rest_bone, rest_ref))  # noqa: E731
    jump_ours = np.abs(np.asarray(smooth(before) - smooth(after))).max()
    assert jump_seed > 0.5 and jump_ours < 1e-3


def test_smooth_frame_has_finite_gradients_along_the_parent_axis():
    rest_bone, rest_ref = jnp.array([0.0, 0.0, -1.0]), jnp.array([1.0, 0.0, 0.0])
    f = lambda b: db.local_frame(b, db.smooth_reference(b, rest_bone, rest_ref))  # noqa: E731
    # Compiled once for the three bones (op by op, every operation is a program of its own).
    jacobians = (jax.jit(jax.jacfwd(f)), jax.jit(jax.jacrev(f)))
    for bone in ([1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]):
        for jac in jacobians:
            assert np.all(np.isfinite(jac(jnp.asarray(bone))))
    # ...and the seed's fixed reference stays finite (though it jumps) exactly on the axis.
    g = jax.jacfwd(lambda b: db.local_frame(b, jnp.array([1.0, 0.0, 0.0])))(
        jnp.array([2.0, 0.0, 0.0])
    )
    assert np.all(np.isfinite(g))


def test_local_frames_and_descriptors_of_the_body(male50):
    pose = random_pose(male50, np.random.default_rng(14))
    p = db.forward(male50, pose).joint_positions
    frames = np.asarray(db.local_frames(male50, p))
    np.testing.assert_allclose(
        frames @ frames.transpose(0, 2, 1), np.broadcast_to(np.eye(3), frames.shape), atol=1e-12
    )
    prox, dist = np.asarray(male50.proximal_joint), np.asarray(male50.distal_joint)
    bones = np.asarray(p)[dist] - np.asarray(p)[prox]
    np.testing.assert_allclose(
        np.einsum("kij,ki->kj", frames, bones)[1:, 0], male50.lengths[1:], atol=1e-12
    )
    desc = np.asarray(db.bone_descriptors(male50, p))
    np.testing.assert_allclose(desc[1:, 2], male50.lengths[1:], atol=1e-12)  # r is the bone length
    # The descriptors describe the bone in its parent's frame: rebuild it and compare.
    par = np.asarray(male50.parent)
    v = np.asarray(db.inclination_azimuth_to_vector(desc[1:, 0], desc[1:, 1], desc[1:, 2]))
    np.testing.assert_allclose(np.einsum("kij,kj->ki", frames[par[1:]], v), bones[1:], atol=1e-12)


def test_descriptors_are_posture_invariant_to_a_global_turn(male50):
    """Seed 001's point: local descriptors do not depend on where the person faces."""
    pose = random_pose(male50, np.random.default_rng(15))
    turned = eqx.tree_at(lambda p: p.angles, pose, pose.angles.at[0, 2].add(1.0))
    d1 = db.bone_descriptors(male50, db.forward(male50, pose).joint_positions)
    d2 = db.bone_descriptors(male50, db.forward(male50, turned).joint_positions)
    np.testing.assert_allclose(d1, d2, atol=1e-9)
