"""Setting up a reach on the host compiles no program of its own (docs/design.md, section 9,
"Host set-up"): loading the default body, resolving targets and constraints and building an
environment put NumPy-built arrays on the device, and the floor and the planted soles take
the compiled `forward`. Counted with JAX's compile events, never timed."""

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bodies import random_pose

import diffbody as db
from diffbody._body_cache import BodyCache
from diffbody._memory_maps import BACKEND_COMPILE
from diffbody.contact import sole_spheres
from diffbody.problem import _constraints
from diffbody.problem._constraints import GEOMETRY, resolve_constraints
from diffbody.problem._targets import _floor_jit, resolve_targets, standing

FEET = ("left_foot", "right_foot")

# What a fresh process may compile for the set-up below: the standard position and the
# forward kinematics that every pose of the body structure shares (the picture's too).
EXPECTED = {"jit(_rest_pose)", "jit(_forward)"}


@contextlib.contextmanager
def _compiles():
    """The names of the programs compiled (or read from the persistent cache) inside."""
    names: list[str] = []

    def listen(event: str, duration: float, **kwargs) -> None:
        if event == BACKEND_COMPILE:
            names.append(str(kwargs.get("fun_name")))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def _set_up():
    body = db.load_body()
    init = body.rest_pose()
    resolve_targets(body, [db.Target.position("left_hand.palm", [0.35, 0.3, 1.1])])
    targets = standing(body, init)
    targets.append(db.Target.no_contact(environment=db.Environment.of(spheres=[(0, 0, 1, 0.1)])))
    return resolve_constraints(body, targets, init)


def test_setting_up_a_standing_reach_compiles_only_the_forward_kinematics(monkeypatch):
    """From empty caches: no "stage", "convert_element_type", "broadcast_in_dim" or other
    small program, nor one for the floor or the planted soles (before: 33 programs); again:
    nothing at all."""
    monkeypatch.setattr(_constraints, "_HOST", BodyCache(GEOMETRY))
    jax.clear_caches()
    with _compiles() as first:
        _set_up()
    assert set(first) <= EXPECTED, first
    with _compiles() as again:
        _set_up()
    assert again == []


@pytest.fixture(scope="module")
def pose(male50):
    return random_pose(male50, np.random.default_rng(3), position=[0.1, -0.2, 0.05])


def test_the_host_floor_equals_the_compiled_one(male50, pose):
    host = standing(male50, pose)[0].height
    compiled = float(_floor_jit(male50, sole_spheres(male50, FEET), pose))
    assert isinstance(host, float)
    np.testing.assert_allclose(host, compiled, rtol=0, atol=1e-12)


def test_the_host_planting_equals_the_traced_one(male50, pose):
    """The soles' places and the support polygon's edges: the same values (to rounding)
    and dtypes, whether `init` is concrete (NumPy) or traced (jax.jit: one compiled
    function)."""
    targets = standing(male50, pose)
    host = resolve_constraints(male50, targets, pose)
    traced = jax.jit(lambda p: resolve_constraints(male50, targets, p))(pose)
    for a, b in zip(jax.tree.leaves(host), jax.tree.leaves(traced)):
        assert a.dtype == b.dtype and a.shape == b.shape
        if a.dtype == bool:
            np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert np.asarray(host.edge).any()


def test_planting_under_grad_stays_differentiable(male50, pose):
    """A pose traced under jax.grad takes the traced path: moving the body along x moves
    each sole centre with it."""
    targets = standing(male50, pose)

    def along_x(dx):
        moved = dataclasses.replace(pose, position=pose.position + jnp.asarray([dx, 0.0, 0.0]))
        return resolve_constraints(male50, targets, moved).sole_center[:, 0].sum()

    n_sole = len(sole_spheres(male50, FEET))
    np.testing.assert_allclose(jax.grad(along_x)(0.0), n_sole, rtol=1e-12)
