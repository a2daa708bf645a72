"""One attempt of a reach solve: one phase's least-squares solve from one start, in rounds,
and its verdict (docs/design.md, section 6).

Each round is one solve of a `Problem` (one walk per residual evaluation) by the one
least-squares set-up (`_solver.least_squares_solver`, with `EarlyStop`: it stops as soon as
every target row is within a hundredth of its tolerance), compiled once per problem shape
and shared by every start and round. A start runs in rounds of at most `ROUND_STEPS` steps,
each from where the last stopped, until the solver stops or `max_steps` are spent: under
jax.vmap a solve costs its slowest row's steps, so a batch gives the few rows that need
more steps further rounds of their own instead of holding every row to the slowest.

The solver's loop is never differentiated: under differentiation the answer carries the
implicit function theorem's derivatives (`implicit`: one Jacobian at the answer).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from .._body import Body, Pose
from .._solver import FitStatus, StopAt, least_squares_solver, solve, tolerance
from ..problem._constraints import WEIGHT, row_count
from ..problem._problem import Problem, make_problem
from ..problem._targets import TargetSet, mask_invalid
from ..problem._tree import Plan
from ..problem._unknowns import Layout
from ._limb_start import limb_start
from ._starts import nth_start

# Steps per round. From the closed-form limb start, 95 % of the left arm's palm targets
# are reached within 8 steps and 99.5 % within 30 (benchmarks/solvers.py): a round of 10
# holds a batch to 10 steps and gives the rest further rounds.
ROUND_STEPS = 10


class Attempt(eqx.Module):
    """One solve from one start, in one phase."""

    pose: Pose
    err_p: Array  # (n_p,) m
    err_a: Array  # (n_a,) rad
    ok: Array  # every valid target within the tolerance
    cost: Array  # sum of weighted squared errors (inf when not finite)
    steps: Array


class Settings(eqx.Module):
    """What a reach's rounds are asked beside their problem, targets and start: what counts
    as reached (m, rad; data, so that every tolerance shares a program), and whether the
    first start is the closed-form limb start (static; on a plan the plan says,
    `Plan.closed`)."""

    tol_position: Float[Array, ""]
    tol_angle: Float[Array, ""]
    closed_form: bool = eqx.field(static=True, default=False)


def reach_solver(dtype) -> optx.AbstractLeastSquaresSolver:
    """The solver of a reach round in `dtype`: `least_squares_solver` with the early stop,
    rtol = atol = 1e-6 in float32 (which cannot resolve relative changes of 1e-8), 1e-8 in
    float64. Levenberg-Marquardt with the damped normal equations by Cholesky: from the
    closed-form start it reaches 95.0 % of 1,000 left-arm palm targets within 8 steps, where
    Gauss-Newton reaches 91.0 % and Dogleg 91.3 %, and its damped steps keep the spine's
    bend progressive (the reach ladder); Cholesky and QR reach the same targets at the same
    speed (benchmarks/solvers.py)."""
    return least_squares_solver(tolerance(dtype, 1e-6, 1e-8), early_stop=True)


def _residuals(x: Array, args: tuple[Problem, TargetSet, StopAt]) -> Array:
    problem, targets, _ = args
    return problem.residuals(x, targets)


def _close_enough(targets: TargetSet, settings: Settings, n_constraint_rows: int, cap) -> StopAt:
    """Per target and constraint row (the first rows of `Problem.rows`), the weighted
    residuals below which the solve stops (a hundredth of the tolerance), or stops once it
    has settled (half the tolerance in each component: within 0.87 of it as a vector, so a
    settled answer is a reached one); at most `cap` steps."""
    p = jnp.repeat(targets.point_weight * settings.tol_position, 3)
    a = jnp.repeat(targets.axis_weight * settings.tol_angle, 3)
    c = jnp.full(n_constraint_rows, WEIGHT * settings.tol_position)
    tol = jnp.concatenate([p, a, c])
    return StopAt(0.01 * tol, 0.5 * tol, cap)


def no_gradient(tree):
    """The tree with every array's derivatives stopped."""
    return jax.tree.map(lambda a: jax.lax.stop_gradient(a) if eqx.is_array(a) else a, tree)


def implicit(problem: Problem, targets: TargetSet, x: Array) -> Array:
    """x, a minimiser of |residuals|^2 found without differentiating the solver, given the
    derivatives of the implicit function theorem with respect to everything the problem
    and the targets depend on: dx = -pinv(J) dr, with J = d residuals / dx at x (full
    column rank thanks to the pull rows). This is exact where the targets are reached (the
    residuals' curvature term vanishes with them) and first order otherwise. Its value is
    x itself.

    Why not optimistix's `ImplicitAdjoint` (which every other fit uses through
    `optx.least_squares`): a reach keeps one answer out of several starts and phases, and
    its solves run without derivatives, so one compiled solve serves differentiated and
    plain calls alike; and it compiles and runs in about half the time (docs/benchmarks.md,
    "Inverse kinematics")."""
    x = jax.lax.stop_gradient(x)
    fixed = no_gradient((problem, targets))
    J = jax.jacfwd(lambda x: fixed[0].residuals(x, fixed[1]))(x)
    r = problem.residuals(x, targets)
    return x - jnp.linalg.pinv(J) @ (r - jax.lax.stop_gradient(r))


def start_vector(
    problem: Problem, targets: TargetSet, start: Int[Array, ""], closed_form: bool
) -> Float[Array, " n_free"]:
    """The free vector of start `start` (traced): 0 is the closed-form limb start when
    `closed_form` (the first phase), else the problem's start; then the Halton points of
    `_starts`."""
    layout = problem.layout
    first = limb_start(problem.body, layout, targets, problem) if closed_form else problem.x0
    n_trunk = (3 if layout.spine else 0) + (6 if layout.root else 0)
    plan = problem.plan
    if plan is None:
        return nth_start(first, problem.x0, start, n_trunk)
    first = jnp.where(plan.closed, first, problem.x0)
    return nth_start(first, problem.x0, start, n_trunk, plan.free)


def solve_free(
    problem: Problem,
    targets: TargetSet,
    x: Float[Array, " n_free"],
    start: Int[Array, ""],
    fresh: Bool[Array, ""],
    max_steps: int,
    settings: Settings,
    cap: Int[Array, ""] | None = None,
    solver: optx.AbstractLeastSquaresSolver | None = None,
) -> tuple[Float[Array, " n_free"], Int[Array, ""], Bool[Array, ""]]:
    """One round of one phase's solve of `problem` (`make_problem`'s; its derivatives are
    stopped here): from start `start` when `fresh`, else from x (the last round's answer),
    at most `max_steps` steps (static: the compiled loop's bound), or `cap` steps (data,
    <= max_steps: every cap shares one program). Returns the free vector, the steps and
    whether the solve has ended (stopped early, converged, or left the finite numbers: then
    it falls back to where the round began). Non-finite targets take no part. Never
    differentiated (see `assess`). `solver`: by default `reach_solver` (any optimistix
    least-squares solver runs on the same problem; only `EarlyStop` reads the last element
    of the args, `StopAt`)."""
    problem, targets, x, settings = no_gradient((problem, targets, x, settings))
    safe, _, _ = mask_invalid(targets)
    x0 = start_vector(problem, safe, start, settings.closed_form)
    x0 = jnp.where(fresh, x0, x)
    if not problem.layout.n_free:
        return x0, jnp.asarray(0), jnp.asarray(True)
    n_constraint_rows = row_count(safe.constraints)
    cap = jnp.asarray(max_steps if cap is None else cap)
    args = (problem, safe, _close_enough(safe, settings, n_constraint_rows, cap))
    solver = reach_solver(x0.dtype) if solver is None else solver
    out = solve(_residuals, solver, x0, args, max_steps)
    return out.value, jnp.asarray(out.steps), out.status != FitStatus.NOT_CONVERGED


def assess(
    problem: Problem,
    init: Pose,
    targets: TargetSet,
    x: Float[Array, " n_free"],
    steps: Int[Array, ""],
    settings: Settings,
    differentiable: bool = False,
) -> Attempt:
    """The pose (from `init`), errors and verdict of a solved free vector of `problem`;
    with `differentiable`, the answer carries the implicit function theorem's derivatives
    (`implicit`)."""
    safe, ok_p, ok_a = mask_invalid(targets)
    tol_position, tol_angle = settings.tol_position, settings.tol_angle
    if differentiable and problem.layout.n_free:
        x = implicit(problem, safe, x)
    err_p, err_a, violation = problem.errors(x, safe)
    ok = jnp.all(jnp.where(ok_p, err_p <= tol_position, True))
    ok &= jnp.all(jnp.where(ok_a, err_a <= tol_angle, True))
    ok &= jnp.all(violation <= tol_position)
    cost = jnp.sum(safe.point_weight * err_p**2) + jnp.sum(safe.axis_weight * err_a**2)
    cost = cost + WEIGHT**2 * jnp.sum(violation**2)
    cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf)
    return Attempt(problem.pose(x, init), err_p, err_a, ok, cost, steps)


def attempt_round(
    body: Body,
    layout: Layout,
    init: Pose,
    targets: TargetSet,
    x: Float[Array, " n_free"],
    start: Int[Array, ""],
    fresh: Bool[Array, ""],
    cap: Int[Array, ""],
    settings: Settings,
    plan: Plan | None = None,
) -> tuple[Float[Array, " n_free"], Bool[Array, ""], Attempt]:
    """One round (`solve_free`) of at most `cap` <= `ROUND_STEPS` steps (data), assessed
    (no derivatives): the free vector to go on from, whether the solve has ended, and the
    attempt (its steps: this round's). The problem is built once and shared. `plan`: the
    whole tree's or a limb chain's (`_tree`): then the plan says whether the first start
    is the limb start (`settings.closed_form` True)."""
    problem = make_problem(no_gradient(body), layout, no_gradient(init), no_gradient(plan))
    x, steps, done = solve_free(problem, targets, x, start, fresh, ROUND_STEPS, settings, cap)
    return x, done, assess(problem, init, targets, x, steps, settings)


# Standing, a phase may take this many times `max_steps`: the planted feet close a loop
# through the legs and the pelvis, so its steps are shorter and a far reach needs more of
# them (docs/benchmarks.md, "Inverse kinematics").
STANDING_STEPS = 4


def phase_steps(layout: Layout, max_steps: int) -> int:
    """The step budget of a start in a phase: `max_steps`, standing `STANDING_STEPS` times."""
    return int(max_steps) * (STANDING_STEPS if layout.standing else 1)


def round_caps(max_steps: int) -> list[int]:
    """The step caps of a start's rounds: `ROUND_STEPS` each, the last what is left."""
    full, rest = divmod(int(max_steps), ROUND_STEPS)
    return [ROUND_STEPS] * full + ([rest] if rest else [])


def better(a: Attempt, b: Attempt) -> Array | np.ndarray | np.bool_:
    """Whether attempt a should replace b: it reaches where b does not, or comes closer
    (elementwise for attempts of many rows, jax or numpy)."""
    return (a.ok & ~b.ok) | ((a.ok == b.ok) & (a.cost < b.cost))
