"""Reach: inverse kinematics with optimistix (docs/design.md, section 6).

A solve runs in phases, as a person reaches: first the limbs (every unknown below the
trunk: clavicle, arm, hand; thigh, shank, foot; the head on the neck), with the spine, the
pelvis and the whole body held as in `init`; only if that misses, the trunk joins (the
spine as its Bendspine target, the root's placement when free), starting from the limbs'
closest reach. Within a phase, starts are tried in turn (`init` first, then the fixed
points of `_starts`) until every target is reached, unless the target lies beyond the
phase's reach bound (the sum of its chain's lengths), which decides up front that no start
can reach it.

Each attempt is one optimistix least-squares solve of a `Problem` (one walk per residual
evaluation), compiled once per problem shape, that stops as soon as every target is well
within its tolerance. The solver's loop is never differentiated: under differentiation the
answer carries the implicit function theorem's derivatives (`implicit`: one Jacobian at
the answer), so jax.grad of a solve costs about one residual Jacobian more. Called with
concrete inputs, `solve_reach` drives the phases and starts from the host, so only what a
target needs is ever compiled or run. Under a JAX transformation (jax.grad, jax.jit,
jax.vmap of `solve_reach`), the same attempts run side by side and the kept one is selected
with `jnp.where`.
"""

import enum
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._body import Body, Pose
from .._spine import spine_angles
from ._post_projection import needs_projection, project_to_standard, twists_to_keep
from ._problem import Problem, make_problem, reach_bound, start_links
from ._starts import nth_start
from ._targets import Target, TargetSet, flatten_targets, mask_invalid, resolve_targets
from ._unknowns import Layout, make_layout, path_to_top


class ReachStatus(enum.IntEnum):
    """What a reach solve reports (`ReachResult.status`)."""

    SUCCESS = 0  # every valid target reached within the tolerance
    NOT_REACHED = 1  # a target missed although no bound rules it out: the closest reach found
    UNREACHABLE = 2  # a target lies beyond the reach of its chain: the closest reach
    INVALID_TARGET = 3  # a target is not finite: it took no part (the others were solved)

    def describe(self) -> str:
        return _DESCRIPTIONS[self]


_DESCRIPTIONS = {
    ReachStatus.SUCCESS: "reached",
    ReachStatus.NOT_REACHED: "not reached: no start found a posture within the tolerance",
    ReachStatus.UNREACHABLE: "not reached: target outside the reach envelope",
    ReachStatus.INVALID_TARGET: "invalid target (not finite): ignored",
}


# solve_reach returns device arrays; solve_reach_batch returns host (numpy) arrays with a
# leading batch axis.
_Arr = Array | np.ndarray


class ReachResult(eqx.Module):
    """What `solve_reach` returns; per-target arrays follow the order the targets were given
    in (a `Target.frame` counts as two targets, its X then its Z axis)."""

    pose: Pose
    reached: Bool[_Arr, "*batch n_targets"]  # within the tolerance (1 mm / 1 degree by default)
    residuals: Float[_Arr, "*batch n_targets"]  # m for points, rad for axes; 0 where not valid
    valid: Bool[_Arr, "*batch n_targets"]  # False for a non-finite target (then never reached)
    beyond: Bool[_Arr, "*batch n_targets"]  # farther than the sum of its chain's lengths
    status: Int[_Arr, "*batch"]  # a ReachStatus
    steps: Int[_Arr, "*batch"]  # solver steps over every attempt


class Attempt(eqx.Module):
    """One solve from one start, in one phase."""

    pose: Pose
    err_p: Array  # (n_p,) m
    err_a: Array  # (n_a,) rad
    ok: Array  # every valid target within the tolerance
    cost: Array  # sum of weighted squared errors (inf when not finite)
    steps: Array


# --- one attempt -------------------------------------------------------------------------
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


def _solver(dtype) -> optx.AbstractLeastSquaresSolver:
    # float32 cannot resolve relative changes of 1e-8, so its tolerance is looser.
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


def _no_gradient(tree):
    return jax.tree.map(lambda a: jax.lax.stop_gradient(a) if eqx.is_array(a) else a, tree)


def implicit(problem: Problem, targets: TargetSet, x: Array) -> Array:
    """x, a minimiser of |residuals|^2 found without differentiating the solver, given the
    derivatives of the implicit function theorem with respect to everything the problem
    and the targets depend on: dx = -pinv(J) dr, with J = d residuals / dx at x (full
    column rank thanks to the pull rows). This is exact where the targets are reached (the
    residuals' curvature term vanishes with them) and first order otherwise. Its value is
    x itself."""
    x = jax.lax.stop_gradient(x)
    fixed = _no_gradient((problem, targets))
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
) -> tuple[Float[Array, " n_free"], Int[Array, ""]]:
    """The free vector one phase's solve reaches from start `start` (traced: 0 is `init`),
    and its steps. Non-finite targets take no part; a solve that leaves the finite numbers
    falls back to its start. Never differentiated (see `assess`)."""
    body, init, targets, tol_position, tol_angle = _no_gradient(
        (body, init, targets, tol_position, tol_angle)
    )
    safe, _, _ = mask_invalid(targets)
    problem = make_problem(body, layout, init)
    n_trunk = (3 if layout.spine else 0) + (6 if layout.root else 0)
    x0 = nth_start(problem.x0, start, n_trunk)
    if not layout.n_free:
        return x0, jnp.asarray(0)
    args = (problem, safe, _close_enough(safe, tol_position, tol_angle))
    sol = optx.least_squares(
        _residuals, _solver(x0.dtype), x0, args, max_steps=max_steps, throw=False
    )
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


def _all_starts(body, layout, init, targets, starts: int, max_steps: int, tol_p, tol_a):
    """Every start side by side: the free vector of the first that reaches (else of the
    closest) and the steps of all."""

    def one(k):
        x, steps = solve_free(body, layout, init, targets, k, max_steps, tol_p, tol_a)
        return x, assess(body, layout, init, targets, x, steps, tol_p, tol_a)

    xs, tries = jax.vmap(one)(jnp.arange(starts))
    k = jnp.where(jnp.any(tries.ok), jnp.argmax(tries.ok), jnp.argmin(tries.cost))
    return xs[k], jnp.sum(tries.steps)


# Compiled once per problem shape and reused by every later call (under jax.grad too: their
# inputs carry no derivatives, so the compiled solve is the same).
_all_starts_jit = eqx.filter_jit(_all_starts)
_assess_jit = eqx.filter_jit(assess)
_attempt_jit = eqx.filter_jit(attempt)


def finish(body: Body, pose: Pose, keep: tuple[int, ...] | None) -> Pose:
    """The post-projection, when asked for (`keep` None: none)."""
    return pose if keep is None else project_to_standard(body, pose, keep)


# --- phases ------------------------------------------------------------------------------
def trunk_segments(body: Body) -> set[int]:
    """The whole body, the spine's segments and everything above them (the pelvis)."""
    trunk = {0}
    if body.spine is not None:
        for name in body.spine.segment_names:
            trunk |= set(path_to_top(body, body.segment_index(name)))
    return trunk


def phase_layouts(
    body: Body,
    ts: TargetSet,
    *,
    spine: bool,
    free_root: bool,
    segments: Sequence[str] | None,
) -> list[Layout]:
    """The layouts of the phases: the limbs alone, then everything (one layout when the two
    coincide or the limbs have no unknown on a target's chain). Cached per body structure
    and limits (host work of milliseconds, on every call otherwise)."""
    ranges = (body.swing_lo, body.swing_hi, body.twist_lo, body.twist_hi)
    if _is_traced(ranges):
        return _phase_layouts(body, ts, spine, free_root, segments)
    key = (
        jax.tree.structure(body),
        tuple(np.asarray(a).tobytes() for a in ranges),
        ts.point_index,
        ts.axis_segment,
        spine,
        free_root,
        None if segments is None else tuple(segments),
    )
    if key not in _LAYOUTS:
        _LAYOUTS[key] = _phase_layouts(body, ts, spine, free_root, segments)
    return _LAYOUTS[key]


_LAYOUTS: dict = {}


def _phase_layouts(body, ts, spine, free_root, segments) -> list[Layout]:
    points, axes = ts.point_index, ts.axis_segment
    movable = set(range(body.n_segments))
    if segments is not None:
        movable = {body.segment_index(name) for name in segments}
    full = make_layout(body, points, axes, movable, spine, free_root)
    limbs = make_layout(body, points, axes, movable - trunk_segments(body), False, False)
    if limbs.n_free == 0 or limbs.n_free == full.n_free:
        return [full]
    return [limbs, full]


def beyond_bound(body: Body, layout: Layout, init: Pose, xyz: ArrayLike) -> np.ndarray:
    """Whether point targets xyz (..., n_p, 3) lie beyond the phase's reach bound (host)."""
    links = jax.tree.map(np.asarray, _start_links_jit(body, init)[0])
    anchor, bound = reach_bound(body, layout, links)
    xyz = np.asarray(xyz, float)
    with np.errstate(invalid="ignore", over="ignore"):
        # |xyz - anchor| scaled by its largest component, so 1e30 m does not overflow.
        d = xyz - anchor
        scale = np.max(np.abs(d), axis=-1)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        dist = scale * np.linalg.norm(d / scale[..., None], axis=-1)
        return np.isfinite(xyz).all(-1) & (dist > bound)


_start_links_jit = eqx.filter_jit(start_links)


def _better(a: Attempt, b: Attempt) -> Array:
    """Whether attempt a should replace b: it reaches where b does not, or comes closer."""
    return (a.ok & ~b.ok) | ((a.ok == b.ok) & (a.cost < b.cost))


def _select(take: Array, a, b):
    return jax.tree.map(lambda x, y: jnp.where(take, x, y), a, b)


# --- the solve ---------------------------------------------------------------------------
def is_none(x) -> bool:
    return x is None


def _is_traced(*trees) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees))


def _solve_host(body, layouts, init, ts, starts, max_steps, tols):
    """Phases and starts driven from the host: each attempt runs only if needed."""
    best, steps = None, 0
    beyond_final = np.zeros(ts.point_xyz.shape[0], bool)
    start_pose = init
    for layout in layouts:
        beyond = beyond_bound(body, layout, start_pose, ts.point_xyz)
        beyond_final = beyond
        for k in range(starts if not beyond.any() else 1):
            a = _attempt_jit(body, layout, start_pose, ts, jnp.asarray(k), max_steps, *tols)
            steps += int(a.steps)
            if best is None or bool(_better(a, best)):
                best = a
            if bool(a.ok):
                return best, steps, beyond
        start_pose = best.pose  # the trunk joins from the limbs' closest reach
    return best, steps, beyond_final


def _solve_traced(body, layouts, init, ts, starts, max_steps, tols):
    """The same phases with every start side by side (for jax.grad / jit / vmap): each
    phase's solve runs without derivatives, and its answer is differentiated implicitly."""
    best, steps = None, jnp.asarray(0)
    start_pose = init
    for layout in layouts:
        b0, p0, t0, tp0, ta0 = _no_gradient((body, start_pose, ts, *tols))
        x, s = _all_starts_jit(b0, layout, p0, t0, starts, max_steps, tp0, ta0)
        a = _assess_jit(body, layout, start_pose, ts, x, s, *tols, True)
        steps = steps + s
        if best is not None and (a.pose.spine_target is None) != (best.pose.spine_target is None):
            # The limbs' phase leaves the spine as in init: name it as a target, so that
            # both phases' poses have one structure to select between.
            total = spine_angles(body, body.spine, init).sum(0)
            best = eqx.tree_at(lambda b: b.pose.spine_target, best, total, is_leaf=is_none)
        best = a if best is None else _select(_better(a, best), a, best)
        start_pose = best.pose
    beyond = np.zeros(ts.point_xyz.shape[0], bool)
    return best, steps, beyond


def solve_reach(
    body: Body,
    targets: Sequence[Target | list[Target]],
    *,
    init: Pose | None = None,
    spine: bool = True,
    free_root: bool = False,
    segments: Sequence[str] | None = None,
    starts: int = 8,
    standard_orientation: bool = True,
    max_steps: int = 30,
    tol_position: float = 1e-3,
    tol_angle: float = float(np.deg2rad(1.0)),
) -> ReachResult:
    """Reach targets with the body (inverse kinematics, docs/design.md, section 6).

    Unknowns: the swing vector and twist, within their limits, of every segment on a
    target's chain (or of those named in `segments`; a segment whose ranges are all zero
    stays as in `init`); the spine as its Bendspine target 3-vector when the body has a
    spine database and `spine` is True; the whole body's placement when `free_root`. Limits
    hold exactly by construction (bounded maps, `diffbody._unknowns`).

    The limbs move first; the trunk (spine, root) joins only for what they cannot reach
    (module docstring). Each phase tries `init` (or the limbs' closest reach), then up to
    `starts - 1` further starts, until every target is reached; a target beyond its chain's
    total length spends one start. Then the standard orientation is restored
    (`standard_orientation`): twists no target depends on return to the standard
    orientation, joints unchanged. An unreachable target gives the closest reach with
    `reached` False; a solve that misses is a status, never an exception or a NaN.

    Args:
        body: the body.
        targets: `Target.position(...)`, `Target.axis_direction(...)`, `Target.frame(...)`.
        init: the starting pose (default: the standard position).
        spine, free_root, segments: which unknowns exist (above).
        starts: the most starts per phase (>= 1).
        standard_orientation: apply the post-projection.
        max_steps: solver steps per start (>= 1).
        tol_position, tol_angle: what counts as reached (m, rad; > 0).

    Returns:
        `ReachResult`: the pose; per target `reached`, `residuals`, `valid`, `beyond`; the
        `status` (a `ReachStatus`) and the solver `steps` over all attempts.

    Raises:
        KeyError: an unknown effector or segment name (the message lists the valid ones).
        ValueError: a non-finite or malformed target, a bad weight, or a setting out of range.
    """
    check_settings(
        starts=starts, max_steps=max_steps, tol_position=tol_position, tol_angle=tol_angle
    )
    flat = flatten_targets(targets)
    for t in flat:
        if isinstance(t.value, jax.core.Tracer):  # under a transformation: masked in the solve
            continue
        if not np.all(np.isfinite(t.value)):
            raise ValueError(f"solve_reach: target {t.name!r} has a non-finite value {t.value}")
    ts, order = resolve_targets(body, flat)
    init = _rest_pose_jit(body) if init is None else init
    layouts = phase_layouts(body, ts, spine=spine, free_root=free_root, segments=segments)
    dtype = jnp.result_type(float)
    tols = (jnp.asarray(tol_position, dtype), jnp.asarray(tol_angle, dtype))
    run = _solve_traced if _is_traced(body, init, ts) else _solve_host
    best, steps, beyond = run(body, layouts, init, ts, int(starts), int(max_steps), tols)
    final = layouts[-1]
    keep = (
        twists_to_keep(body, final)
        if (standard_orientation and needs_projection(body, final))
        else None
    )
    return _conclude_jit(body, keep, best, ts, tuple(order), beyond, steps, tols)


_rest_pose_jit = eqx.filter_jit(lambda body: body.rest_pose())


def _result(pose, best: Attempt, ts: TargetSet, order, beyond, steps, tols) -> ReachResult:
    valid = jnp.concatenate(
        [jnp.all(jnp.isfinite(ts.point_xyz), -1), jnp.all(jnp.isfinite(ts.axis_direction), -1)]
    )
    residuals = jnp.where(valid, jnp.concatenate([best.err_p, best.err_a]), 0.0)
    n_a = ts.axis_direction.shape[0]
    beyond = jnp.concatenate([jnp.asarray(beyond, bool), jnp.zeros(n_a, bool)])
    tol_position, tol_angle = tols
    reached = valid & jnp.concatenate([best.err_p <= tol_position, best.err_a <= tol_angle])
    back = np.argsort(order)
    status = reach_status(reached, valid, beyond)
    return ReachResult(
        pose=pose,
        reached=reached[back],
        residuals=residuals[back],
        valid=valid[back],
        beyond=beyond[back],
        status=status,
        steps=jnp.asarray(steps),
    )


def _conclude(body, keep, best: Attempt, ts, order, beyond, steps, tols) -> ReachResult:
    """The post-projection (when `keep` is not None) and the result, in one compiled call."""
    return _result(finish(body, best.pose, keep), best, ts, order, beyond, steps, tols)


_conclude_jit = eqx.filter_jit(_conclude)


def reach_status(reached: Array, valid: Array, beyond: Array) -> Array:
    ok = jnp.all(reached | ~valid)
    return jnp.where(
        jnp.all(reached),
        ReachStatus.SUCCESS,
        jnp.where(
            jnp.any(beyond & ~reached),
            ReachStatus.UNREACHABLE,
            jnp.where(ok, ReachStatus.INVALID_TARGET, ReachStatus.NOT_REACHED),
        ),
    ).astype(int)


def check_settings(**settings) -> None:
    """Host-side checks of the solve's settings, each naming the argument."""
    for name in ("starts", "max_steps"):
        v = settings[name]
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"solve_reach: {name} must be an integer >= 1, got {v!r}")
    for name in ("tol_position", "tol_angle"):
        v = settings[name]
        if isinstance(v, jax.core.Tracer):
            continue
        if not (np.isfinite(float(v)) and float(v) > 0):
            raise ValueError(f"solve_reach: {name} must be a finite number > 0, got {v!r}")
