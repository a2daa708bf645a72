"""Shared fixtures of the viewer's tests: a short sequence whose frames differ visibly."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db


@pytest.fixture(scope="session")
def arm_raise(male50):
    """(poses, times): both arms raised forward from the sides (polar angle 180 -> 60 deg)
    over 5 frames at 30 frames/s."""
    rest = male50.rest_pose()
    arms = np.array([male50.segment_index(s) for s in ("left_upper_arm", "right_upper_arm")])

    def raised(phi):
        return db.Pose(rest.position, rest.angles.at[arms, 1].set(phi))

    n = 5
    return jax.vmap(raised)(jnp.linspace(jnp.pi, jnp.pi / 3, n)), np.arange(n) / 30.0
