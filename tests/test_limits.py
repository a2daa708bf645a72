"""Joint limits: the default tolerance of `within_limits` follows the dtype."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bodies import random_pose

import diffbody as db


def _as_float32(tree):
    return jax.tree.map(lambda x: x.astype(jnp.float32) if eqx.is_inexact_array(x) else x, tree)


@pytest.fixture(scope="module", params=["male50", "female50"])
def body32(request) -> db.Body:
    body = _as_float32(db.load_body(variant=request.param))
    leaves = [x for x in jax.tree.leaves(body) if eqx.is_inexact_array(x)]
    assert leaves and all(x.dtype == jnp.float32 for x in leaves)
    return body


def test_rest_pose_within_limits_in_float32(body32):
    # Regression: a fixed 1e-9 rad tolerance sat below float32 rounding of the swing vector
    # (~1e-7 rad), so the standard position itself was rejected at the pelvis and forearms.
    rest = body32.rest_pose()
    assert rest.angles.dtype == jnp.float32
    assert db.stop_violation(body32, rest).dtype == jnp.float32
    ok = np.asarray(db.within_limits(body32, rest))
    assert ok.all(), [n for n, k in zip(body32.segment_names, ok) if not k]


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_poses_on_the_limits_are_within(male50, dtype):
    # random_pose puts the swing of cone-limited segments exactly on the cone.
    rng = np.random.default_rng(0)
    poses = [random_pose(male50, rng) for _ in range(64)]
    poses = jax.tree.map(lambda *x: jnp.stack(x).astype(dtype), *poses)
    body = _as_float32(male50) if dtype == jnp.float32 else male50
    ok = jax.vmap(lambda p: db.within_limits(body, p))(poses)
    assert bool(jnp.all(ok))


def test_default_tolerance_is_strict_in_float64(male50):
    # 1e-10 rad past a twist limit: far above float64 rounding, so rejected.
    i = male50.segment_index("left_forearm")
    rest = male50.rest_pose()
    angles = rest.angles.at[i, 2].set(male50.twist_hi[i] + 1e-10)
    ok = np.asarray(db.within_limits(male50, db.Pose(rest.position, angles)))
    assert not ok[i] and ok[np.arange(male50.n_segments) != i].all()


def test_float32_still_rejects_a_real_violation(body32):
    i = body32.segment_index("left_forearm")
    rest = body32.rest_pose()
    angles = rest.angles.at[i, 2].set(body32.twist_hi[i] + 1e-3)
    ok = np.asarray(db.within_limits(body32, db.Pose(rest.position, angles)))
    assert not ok[i] and ok[np.arange(body32.n_segments) != i].all()
