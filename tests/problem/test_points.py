"""The one point kernel (diffbody.problem._points): its closed-form Jacobian against autodiff
through the walk (float64, to 1e-10) on random poses, at the poles of the sockets (the
standard position: every hanging limb and the spine) and at the limits (free variables at
their bounds, where the bounded maps are flat); reverse mode and finite differences of
functions built on it; and the effectors it places against `forward`."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody.problem._constraints import resolve_constraints
from diffbody.problem._points import tree_points, walk_points
from diffbody.problem._problem import make_problem
from diffbody.problem._targets import resolve_targets
from diffbody.problem._terms import cog_term, place, sphere_term, target_terms
from diffbody.problem._unknowns import make_layout, whole_tree_layout


def _points(body, lay, rng, k=12):
    """k random points on random slots of the layout (chain and bases): offsets within
    20 cm, heights anywhere along (and beyond) their segments."""
    n_slots = lay.chain.size + len([b for b in lay.bases if b >= 0])
    slots = tuple(int(s) for s in rng.integers(0, n_slots, size=k))
    offsets = jnp.asarray(0.2 * rng.standard_normal((k, 3)))
    heights = jnp.asarray(rng.uniform(-0.1, 0.6, size=k))
    return slots, offsets, heights


def _layouts(body):
    """Layouts covering every part of the free vector: the whole tree (root, spine, the
    center of gravity), the left arm hanging from fixed bases, the right leg with the
    spine."""
    arm = [body.segment_index(s) for s in ("left_upper_arm", "left_forearm", "left_hand")]
    palm = body.n_joints + body.feature_names.index("left_hand.palm")
    foot = body.n_joints + body.feature_names.index("right_foot.toe")
    everything = range(body.n_segments)
    return {
        "whole": whole_tree_layout(body),
        "arm": make_layout(body, [palm], [], arm, spine=False, root=False),
        "leg": make_layout(body, [foot], [arm[1]], everything, spine=True, root=False),
    }


@pytest.fixture(scope="module")
def cases(male50):
    """Per layout, its points and one compiled function of (problem, lengths, offsets,
    heights, x) giving the kernel, the walk, and the three Jacobians; per kind of pose, its
    problem and free vector."""
    body = male50
    rng = np.random.default_rng(0)
    out = []
    for name, lay in _layouts(body).items():
        slots, offsets, heights = _points(body, lay, rng)
        # Reverse mode of the whole tree is checked by the marker kernel's tests
        # (tests/mocap/test_mocap.py, root and spine free): here it would double the
        # largest compile of the suite.
        reverse = name != "whole"
        compiled = jax.jit(functools.partial(_kernel_and_jacobians, slots, reverse))
        for kind in ("random", "rest", "limits"):
            pose = (
                body.rest_pose()
                if kind != "random"
                else db.sample_pose(body, jax.random.PRNGKey(len(out)), spread=0.5)
            )
            problem = make_problem(body, lay, pose)
            x = problem.x0
            if kind == "random":
                x = x + 0.3 * rng.standard_normal(x.shape)
            elif kind == "limits":
                # Every bounded variable at a bound (sin map flat), the root moved.
                # Strongly typed, as the other kinds' x: a weak type would compile again.
                x = jnp.asarray(np.where(np.arange(x.shape[0]) % 2 == 0, np.pi / 2, -np.pi / 2))
                if lay.root:
                    x = x.at[-6:].set(jnp.asarray([0.1, -0.2, 0.05, 0.3, -0.2, 1.0]))
            args = (body.lengths, offsets, heights, x)
            out.append((f"{name}-{kind}", compiled, problem, slots, args))
    return out


def _kernel_and_jacobians(slots, reverse, problem, *args):
    def fast(*a):
        return tree_points(slots, problem, *a)

    def plain(*a):
        return walk_points(problem, slots, *a)[0]

    argnums = (0, 1, 2, 3)
    return (
        fast(*args),
        plain(*args),
        jax.jacfwd(fast, argnums)(*args),
        jax.jacfwd(plain, argnums)(*args),
        jax.jacrev(fast, argnums)(*args) if reverse else None,
    )


def test_jacobian_matches_autodiff_through_the_walk(cases):
    """d points / d (lengths, offsets, heights, x): the closed form equals forward-mode
    autodiff through the walk to 1e-10, and reverse mode equals forward mode (arm and leg
    layouts)."""
    for name, compiled, problem, _, args in cases:
        p_fast, p_plain, J_fast, J_plain, J_rev = compiled(problem, *args)
        np.testing.assert_allclose(p_fast, p_plain, atol=1e-14, err_msg=name)
        for k, (a, b) in enumerate(zip(J_fast, J_plain)):
            assert np.all(np.isfinite(a)), name
            np.testing.assert_allclose(a, b, atol=1e-10, err_msg=name)
            if J_rev is not None:
                np.testing.assert_allclose(J_rev[k], a, atol=1e-10, err_msg=name)


def test_gradient_of_a_loss_matches_finite_differences(cases):
    """jax.grad of a scalar built on the kernel, along random directions, against central
    differences."""
    rng = np.random.default_rng(5)
    _, _, problem, slots, (lengths, offsets, heights, x) = cases[0]
    target = jnp.asarray(rng.standard_normal((len(slots), 3)))

    @jax.jit
    def loss(x):
        return jnp.sum((tree_points(slots, problem, lengths, offsets, heights, x) - target) ** 2)

    g = jax.jit(jax.grad(loss))(x)
    h = 1e-6
    for _ in range(3):
        v = jnp.asarray(rng.standard_normal(x.shape))
        fd = (loss(x + h * v) - loss(x - h * v)) / (2 * h)
        np.testing.assert_allclose(g @ v, fd, rtol=1e-6, atol=1e-8)


def test_effectors_are_where_forward_puts_them(male50):
    """The reach problem's effectors through the kernel (a joint, a feature, the center of
    gravity, an axis) against `forward` of the problem's pose."""
    body = male50
    targets = [
        db.Target.position("left_hand.palm", [0.3, 0.3, 1.0]),
        db.Target.position("center_of_gravity", [0.0, 0.0, 1.0]),
        db.Target.axis_direction("head", [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
    ]
    ts, _ = resolve_targets(body, targets)
    lay = make_layout(body, ts.point_index, ts.axis_segment, range(body.n_segments), True, True)
    pose = db.sample_pose(body, jax.random.PRNGKey(3), spread=0.5)
    problem = make_problem(body, lay, pose)
    x = problem.x0 + 0.2 * jnp.asarray(np.random.default_rng(1).standard_normal(problem.x0.shape))
    p, axes = problem.effectors(x, ts)
    kin = db.forward(body, problem.pose(x, pose))
    f = body.feature_names.index("left_hand.palm")
    np.testing.assert_allclose(p[0], kin.feature_points[f], atol=1e-12)
    np.testing.assert_allclose(p[1], kin.center_of_gravity, atol=1e-12)
    head = body.segment_index("head")
    np.testing.assert_allclose(axes[0], kin.R_world_twisted[head] @ ts.axis_local[0], atol=1e-12)


def test_terms_placed_together_are_each_alone_and_where_forward_puts_them(male50):
    """`_terms.place`: the terms of a standing problem (effectors, an axis, the spheres the
    constraints read, the center of gravity) placed in one call of the kernel equal each
    term placed alone, and `forward` of the problem's pose (sphere centres, center of
    gravity); the problem's rows are its residuals, by term."""
    body = male50
    targets = [
        db.Target.position("left_hand.palm", [0.5, 0.3, 1.0]),
        db.Target.axis_direction("head", [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
        db.Target.no_contact(["left_hand"], margin=0.01),
        db.Target.on_floor(),
        db.Target.balance(),
    ]
    goals, constraints = targets[:2], targets[2:]
    ts, _ = resolve_targets(body, goals)
    init = body.rest_pose()
    c = resolve_constraints(body, constraints, init)
    ts = eqx.tree_at(lambda t: t.constraints, ts, c, is_leaf=lambda x: x is None)
    segments = range(body.n_segments)
    read = tuple(c.segments)
    lay = make_layout(body, ts.point_index, ts.axis_segment, segments, True, True, read, c.feet)
    problem = make_problem(body, lay, init)
    x = problem.x0 + 0.1 * jnp.asarray(np.random.default_rng(2).standard_normal(problem.x0.shape))
    points, axes = target_terms(problem, ts)
    terms = {"palm": points[0], "axes": axes, "spheres": sphere_term(problem, c.spheres)}
    terms["cog"] = cog_term(problem)
    together = place(problem, x, terms)
    for name, term in terms.items():
        np.testing.assert_allclose(
            together[name], place(problem, x, {name: term})[name], atol=1e-14
        )
    kin = db.forward(body, problem.pose(x, init))
    np.testing.assert_allclose(
        together["spheres"], kin.sphere_centers[np.asarray(c.spheres)], atol=1e-12
    )
    np.testing.assert_allclose(together["cog"], kin.center_of_gravity, atol=1e-12)
    rows = problem.rows(x, ts)
    assert [r.shape[0] for r in rows] == [3, 3, rows.constraints.shape[0], lay.n_free]
    np.testing.assert_array_equal(jnp.concatenate(rows), problem.residuals(x, ts))
