"""The one least-squares set-up of every fit (docs/design.md, section 3): reach, motion
capture, the sphere fit and the lifting all solve with `least_squares_solver` through
`solve`, which maps optimistix's outcome to one `FitStatus` and never returns a NaN.

The solver is optimistix's Levenberg-Marquardt, with the linear solve as a parameter: the
damped normal equations by Cholesky (`NORMAL_CHOLESKY`, the default: every fit here has few
unknowns against more rows, made well posed by its pull rows and the damping) or a
structured solve (the lifting's banded Schur complement). Measured against Gauss-Newton and
Dogleg on the reach problem (benchmarks/solvers.py): it reaches the most targets from one
start. `EarlyStop` adds the reach's stop: once every target row is within a hundredth of its
tolerance, waiting for the pull rows to settle would cost most of the steps.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, PyTree

from ._statuses import FitStatus

NORMAL_CHOLESKY = lx.Normal(lx.Cholesky())


def tolerance(dtype, float32: float, float64: float) -> float:
    """The tolerance of a fit in `dtype`: float32 cannot resolve what float64 can."""
    return float64 if jnp.finfo(dtype).bits == 64 else float32


class EarlyStop(optx.LevenbergMarquardt):
    """Levenberg-Marquardt that also stops as soon as the first rows of the residuals are
    each within their bounds, and after a number of steps given as data: the last element
    of `args` is `StopAt(bounds, max_steps)`. A stop at the step cap reports
    `nonlinear_max_steps_reached`, as optimistix's own `max_steps` does, so one compiled
    solve (its static `max_steps` the largest cap) serves every cap below it."""

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        stop = args[-1]
        rows = state.f_info.residual[: stop.bounds.shape[0]]
        reached = ~state.first_step & jnp.all(jnp.abs(rows) <= stop.bounds)
        capped = ~(done | reached) & (state.num_steps >= stop.max_steps)
        result = optx.RESULTS.where(capped, optx.RESULTS.nonlinear_max_steps_reached, result)
        return done | reached | capped, result


class StopAt(NamedTuple):
    """What `EarlyStop` reads from the last element of its args."""

    bounds: Array  # (k,) the first k residual rows' bounds
    max_steps: Array  # () int, the most steps of this solve


def least_squares_solver(
    tol: float | Array,
    *,
    linear_solver: lx.AbstractLinearSolver = NORMAL_CHOLESKY,
    norm=optx.max_norm,
    early_stop: bool = False,
) -> optx.LevenbergMarquardt:
    """Levenberg-Marquardt with rtol = atol = `tol` (a number, or traced: a stage's own)
    under `norm` (max_norm: every unknown
    within tol; rms_norm: on average), the damped steps solved by `linear_solver`;
    `early_stop`: `EarlyStop`."""
    kind = EarlyStop if early_stop else optx.LevenbergMarquardt
    return kind(rtol=tol, atol=tol, norm=norm, linear_solver=linear_solver)


class Solved(NamedTuple):
    value: PyTree  # the answer, or the start where the solve left the finite numbers
    status: Array  # a FitStatus
    steps: Array  # solver steps taken


def solve(fn, solver, y0: PyTree, args, max_steps: int, ok: Array | bool = True) -> Solved:
    """optimistix's least squares of `fn(y, args)` from y0, never raising: a solve that
    leaves the finite numbers (or whose data is not `ok`) returns y0 as FAILED."""
    sol = optx.least_squares(fn, solver, y0, args, max_steps=max_steps, throw=False)
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(sol.value)]))
    ok = finite & ok
    value = jax.tree.map(lambda a, b: jnp.where(ok, a, b), sol.value, y0)
    converged = sol.result == optx.RESULTS.successful
    return Solved(value, status_of(ok, converged), sol.stats["num_steps"])


def status_of(finite: Array, converged: Array) -> Array:
    """The `FitStatus` (int32) of a solve: FAILED where not finite, else whether it
    converged."""
    return jnp.where(
        finite,
        jnp.where(converged, FitStatus.CONVERGED, FitStatus.NOT_CONVERGED),
        FitStatus.FAILED,
    ).astype(jnp.int32)
