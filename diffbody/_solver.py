"""The one least-squares set-up of every fit (docs/design.md, section 3): reach, motion
capture, the sphere fit and the lifting all solve with `least_squares_solver` through
`solve`, which maps optimistix's outcome to one `FitStatus` and never returns a NaN.

The solver is optimistix's Levenberg-Marquardt, with the linear solve as a parameter: the
damped normal equations by Cholesky (`NORMAL_CHOLESKY`, the default: every fit here has few
unknowns against more rows, made well posed by its pull rows and the damping) or a
structured solve (the lifting's banded Schur complement). Measured against Gauss-Newton and
Dogleg on the reach problem (benchmarks/solvers.py): it reaches the most targets from one
start. `EarlyStop` adds the reach's stop: once every target row is within a hundredth of its
tolerance, or within half of it while the steps no longer lower the cost, waiting for the
pull rows to settle would cost most of the steps.
"""

from typing import NamedTuple

import equinox as eqx
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


# A solve within its near bounds stops once an accepted step lowers the sum of squares by
# less than this share: it has settled where its targets meet the pull and the penalties.
# Standing, that compromise leaves a target 0.1-0.3 mm off, and the early stop's hundredth
# of the tolerance was never met: far reaches spent their whole budget (docs/design.md, 6).
SETTLE = 1e-3


class _Settling(eqx.Module):
    trust: PyTree  # the classical trust region's own state
    gain: Array  # () the share of the sum of squares the last accepted step removed


class SettlingTrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region (Levenberg-Marquardt's step-size control,
    unchanged) that also records how much the last accepted step lowered the cost."""

    def init(self, y, f_info_struct) -> _Settling:
        return _Settling(super().init(y, f_info_struct), jnp.asarray(1.0))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state: _Settling):
        size, accept, result, trust = super().step(
            first_step, y, y_eval, f_info, f_eval_info, state.trust
        )
        cost = jnp.sum(f_info.residual**2)
        tiny = jnp.finfo(cost.dtype).tiny
        lowered = (cost - jnp.sum(f_eval_info.residual**2)) / jnp.maximum(cost, tiny)
        gain = jnp.where(accept & ~first_step, lowered, state.gain)
        return size, accept, result, _Settling(trust, gain)


class EarlyStop(optx.LevenbergMarquardt):
    """Levenberg-Marquardt that also stops as soon as the first rows of the residuals are
    each within their `exact` bounds, or within their `near` bounds once an accepted step
    lowered the cost by less than `SETTLE`, and after a number of steps given as data: the
    last element of `args` is `StopAt(exact, near, max_steps)`. A stop at the step cap
    reports `nonlinear_max_steps_reached`, as optimistix's own `max_steps` does, so one
    compiled solve (its static `max_steps` the largest cap) serves every cap below it."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.search = SettlingTrustRegion()

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        stop = args[-1]
        rows = jnp.abs(state.f_info.residual[: stop.exact.shape[0]])
        begun = ~state.first_step
        reached = begun & jnp.all(rows <= stop.exact)
        settled = begun & jnp.all(rows <= stop.near) & (state.search_state.gain < SETTLE)
        ended = done | reached | settled
        capped = ~ended & (state.num_steps >= stop.max_steps)
        result = optx.RESULTS.where(capped, optx.RESULTS.nonlinear_max_steps_reached, result)
        return ended | capped, result


class StopAt(NamedTuple):
    """What `EarlyStop` reads from the last element of its args."""

    exact: Array  # (k,) the first k residual rows' bounds for stopping at once
    near: Array  # (k,) their bounds for stopping once the solve has settled
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
