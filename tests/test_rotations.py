"""`swing_rotation`, the smallest rotation between two directions (every socket frame of
`forward`): against the independent reference of tests/helpers.py over the whole sphere,
nearly opposite directions included; its derivatives (forward mode, reverse mode and central
differences) in both of its branches, and finite at b = a and b = -a."""

import jax
import jax.numpy as jnp
import numpy as np
from helpers import swing_rotation as reference
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from diffbody._rotations import swing_rotation

unit = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(
    lambda v: np.linalg.norm(v) > 0.1
)


@settings(max_examples=200, deadline=None)
@given(unit, unit, st.floats(-9.0, 0.0), st.booleans())
def test_the_smallest_rotation_is_the_reference_one(a, b, log_gap, opposite):
    """R a = b, R a proper rotation, equal to the reference's; b nearly opposite a (within
    10^log_gap) in half the cases, where the formula switches to its far form."""
    a = np.asarray(a) / np.linalg.norm(a)
    b = np.asarray(b) / np.linalg.norm(b)
    if opposite:  # b: -a moved by 10^log_gap across it
        across = b - (b @ a) * a
        assume(np.linalg.norm(across) > 1e-3)
        b = -a + 10.0**log_gap * across / np.linalg.norm(across)
        b = b / np.linalg.norm(b)
    assume(np.linalg.norm(np.cross(a, b)) > 0)  # exactly opposite: the next test
    R = np.asarray(swing_rotation(a, b))
    np.testing.assert_allclose(R @ a, b, atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0
    gap = np.linalg.norm(np.cross(a, b))
    # Near the antipode the rotation's axis is ill-conditioned (1 / |a x b|) in any formula.
    np.testing.assert_allclose(R, reference(a, b), atol=1e-15 / max(gap, 1e-15) + 1e-12)


def test_exactly_opposite_is_a_half_turn_with_finite_derivatives():
    """At b = -a: the half-turn about a x e1 (e1 perpendicular to a, fixed by a alone), and
    finite forward- and reverse-mode derivatives there and at b = a."""
    a = jnp.asarray([0.0, 0.0, 1.0])
    np.testing.assert_allclose(swing_rotation(a, -a), np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    for b in (a, -a):
        for jac in (jax.jacfwd, jax.jacrev):
            assert np.all(np.isfinite(jac(lambda b: swing_rotation(a, b))(b)))


def test_derivatives_match_finite_differences_in_both_branches():
    """d R / d b by forward mode equals reverse mode and central differences, for b on the
    near side (a . b >= 0) and the far side of a."""
    rng = np.random.default_rng(0)
    a = jnp.asarray(rng.standard_normal(3))
    a = a / jnp.linalg.norm(a)
    f = jax.jit(lambda b: swing_rotation(a, b))
    for sign in (1.0, -1.0):
        b = sign * a + 0.6 * jnp.asarray(rng.standard_normal(3))
        b = b / jnp.linalg.norm(b)
        assert (float(a @ b) >= 0) == (sign > 0)
        fwd, rev = jax.jacfwd(f)(b), jax.jacrev(f)(b)
        h = 1e-6
        fd = jnp.stack([(f(b + h * e) - f(b - h * e)) / (2 * h) for e in jnp.eye(3)], -1)
        np.testing.assert_allclose(fwd, rev, atol=1e-12)
        np.testing.assert_allclose(fwd, fd, atol=1e-8)
