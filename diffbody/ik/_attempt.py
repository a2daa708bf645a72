"""One attempt of a reach solve: one phase's least-squares solve from one start, and its
verdict (docs/design.md, section 6).

Each attempt is one optimistix least-squares solve of a `Problem` (one walk per residual
evaluation), compiled once per problem shape, that stops as soon as every target is well
within its tolerance. The solver's loop is never differentiated: under differentiation the
answer carries the implicit function theorem's derivatives (`implicit`: one Jacobian at the
answer), so jax.grad of a solve costs about one residual Jacobian more.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

from .._body import Body, Pose
from ._problem import Problem, make_problem
from ._starts import nth_start
from ._targets import TargetSet, mask_invalid
from ._unknowns import Layout


class Attempt(eqx.Module):
    """One solve from one start, in one phase."""

    pose: Pose
    err_p: Array  # (n_p,) m
    err_a: Array  # (n_a,) rad
    ok: Array  # every valid target within the tolerance
    cost: Array  # sum of weighted squared errors (inf when not finite)
    steps: Array


class _ReachLM(optx.LevenbergMarquardt):
    """optimistix's Levenberg-Marquardt (measured against Gauss-Newton and Dogleg: it reaches
    the most targets from one start), which also stops as soon as every target row is within
    a hundredth of its tolerance: the pull toward the start only settles redundant
    directions, and waiting for it to converge would cost most of the steps."""

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        close_enough = args[2]
        rows = state.f_info.residual[: close_enough.shape[0]]
        reached = ~state.first_step & jnp.all(jnp.abs(rows) <= close_enough)
        return done | reached, result


def reach_solver(dtype) -> optx.AbstractLeastSquaresSolver:
    """The solver of a reach attempt in `dtype`: Levenberg-Marquardt with the early stop
    above, rtol = atol = 1e-6 in float32 (which cannot resolve relative changes of 1e-8),
    1e-8 in float64 (benchmarks/solvers.py compares it with optimistix's other solvers)."""
    tol = 1e-8 if jnp.finfo(dtype).bits == 64 else 1e-6
    return _ReachLM(rtol=tol, atol=tol)


def _residuals(x: Array, args: tuple[Problem, TargetSet, Array]) -> Array:
    problem, targets, _ = args
    return problem.residuals(x, targets)


def _close_enough(targets: TargetSet, tol_position: Array, tol_angle: Array) -> Array:
    """Per target row, the weighted residual below which the solve may stop early."""
    p = jnp.repeat(targets.point_weight * tol_position, 3)
    a = jnp.repeat(targets.axis_weight * tol_angle, 3)
    return 0.01 * jnp.concatenate([p, a])


def no_gradient(tree):
    """The tree with every array's derivatives stopped."""
    return jax.tree.map(lambda a: jax.lax.stop_gradient(a) if eqx.is_array(a) else a, tree)


def implicit(problem: Problem, targets: TargetSet, x: Array) -> Array:
    """x, a minimiser of |residuals|^2 found without differentiating the solver, given the
    derivatives of the implicit function theorem with respect to everything the problem
    and the targets depend on: dx = -pinv(J) dr, with J = d residuals / dx at x (full
    column rank thanks to the pull rows). This is exact where the targets are reached (the
    residuals' curvature term vanishes with them) and first order otherwise. Its value is
    x itself."""
    x = jax.lax.stop_gradient(x)
    fixed = no_gradient((problem, targets))
    J = jax.jacfwd(lambda x: fixed[0].residuals(x, fixed[1]))(x)
    r = problem.residuals(x, targets)
    return x - jnp.linalg.pinv(J) @ (r - jax.lax.stop_gradient(r))


def solve_free(
    body: Body,
    layout: Layout,
    init: Pose,
    targets: TargetSet,
    start: Int[Array, ""],
    max_steps: int,
    tol_position: Float[Array, ""],
    tol_angle: Float[Array, ""],
    solver: optx.AbstractLeastSquaresSolver | None = None,
) -> tuple[Float[Array, " n_free"], Int[Array, ""]]:
    """The free vector one phase's solve reaches from start `start` (traced: 0 is `init`),
    and its steps. Non-finite targets take no part; a solve that leaves the finite numbers
    falls back to its start. Never differentiated (see `assess`). `solver`: by default
    `reach_solver` of the start's dtype (any optimistix least-squares solver runs on the
    same problem; only `reach_solver`'s reads the early-stop rows of its args)."""
    body, init, targets, tol_position, tol_angle = no_gradient(
        (body, init, targets, tol_position, tol_angle)
    )
    safe, _, _ = mask_invalid(targets)
    problem = make_problem(body, layout, init)
    n_trunk = (3 if layout.spine else 0) + (6 if layout.root else 0)
    x0 = nth_start(problem.x0, start, n_trunk)
    if not layout.n_free:
        return x0, jnp.asarray(0)
    args = (problem, safe, _close_enough(safe, tol_position, tol_angle))
    solver = reach_solver(x0.dtype) if solver is None else solver
    sol = optx.least_squares(_residuals, solver, x0, args, max_steps=max_steps, throw=False)
    x = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, x0)
    return x, jnp.asarray(sol.stats["num_steps"])


def assess(
    body: Body,
    layout: Layout,
    init: Pose,
    targets: TargetSet,
    x: Float[Array, " n_free"],
    steps: Int[Array, ""],
    tol_position: Float[Array, ""],
    tol_angle: Float[Array, ""],
    differentiable: bool = False,
) -> Attempt:
    """The pose, errors and verdict of a solved free vector; with `differentiable`, the
    answer carries the implicit function theorem's derivatives (`implicit`)."""
    safe, ok_p, ok_a = mask_invalid(targets)
    problem = make_problem(body, layout, init)
    if differentiable and layout.n_free:
        x = implicit(problem, safe, x)
    err_p, err_a = problem.errors(x, safe)
    ok = jnp.all(jnp.where(ok_p, err_p <= tol_position, True))
    ok &= jnp.all(jnp.where(ok_a, err_a <= tol_angle, True))
    cost = jnp.sum(safe.point_weight * err_p**2) + jnp.sum(safe.axis_weight * err_a**2)
    cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf)
    return Attempt(problem.pose(x, init), err_p, err_a, ok, cost, steps)


def attempt(
    body: Body,
    layout: Layout,
    init: Pose,
    targets: TargetSet,
    start: Int[Array, ""],
    max_steps: int,
    tol_position: Float[Array, ""],
    tol_angle: Float[Array, ""],
) -> Attempt:
    """One phase's solve from start `start`, assessed (no derivatives)."""
    tols = (tol_position, tol_angle)
    x, steps = solve_free(body, layout, init, targets, start, max_steps, *tols)
    return assess(body, layout, init, targets, x, steps, *tols)


def better(a: Attempt, b: Attempt) -> Array | np.ndarray:
    """Whether attempt a should replace b: it reaches where b does not, or comes closer
    (elementwise for attempts of many rows, jax or numpy)."""
    return (a.ok & ~b.ok) | ((a.ok == b.ok) & (a.cost < b.cost))
