"""Reach: inverse kinematics with optimistix (docs/design.md, section 6): `solve_reach`, its
result and its status.

A solve runs in phases, limbs first and the trunk only for what they miss, each trying its
starts in turn until every target is reached (`_phases`); each try is one least-squares
solve, differentiated implicitly (`_attempt`). Then the standard orientation is restored
(`_post_projection`) and the errors are reported per target.
"""

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._body import Body, Pose
from .._body_cache import BodyCache
from .._device_arrays import device_array
from .._programs import compiled
from .._statuses import ReachStatus
from ..problem._constraints import (
    is_constraint,
    pose_violations,
    resolve_constraints,
    target_key,
)
from ..problem._targets import Target, TargetSet, flatten_targets, resolve_targets
from ..problem._targets import standing as standing_targets
from ..problem._tree import padded_targets, targets_rows
from ._attempt import Attempt
from ._phases import is_none, is_traced, phase_layouts, phase_plans, solve_host, solve_traced
from ._post_projection import (
    finish,
    keep_mask,
    needs_projection,
    spine_as_angles,
    vertebrae_mask,
)
from ._reach_bounds import STANDARD_POSITION

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
    # Each constraint kind's violation (m), in `constraint_names` order ("no_contact",
    # "on_floor", "balance"; standing's included): how far the answer breaks it.
    violation: Float[_Arr, "*batch n_constraints"]
    constraint_names: tuple[str, ...] = eqx.field(static=True, default=())


def solve_reach(
    body: Body,
    targets: Sequence[Target | list[Target]],
    *,
    init: Pose | None = None,
    spine: bool = True,
    free_root: bool = False,
    standing: bool = True,
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
    hold exactly by construction (bounded maps, `_unknowns`).

    The limbs move first; the trunk (spine, root) joins only for what they cannot reach
    (`_phases`). When the trunk joins, the body stands (`standing`, the default, unless
    `free_root` or `segments` is given): the pelvis's placement and the legs join the
    spine, the feet stay planted where `init` has them, the centre of gravity stays 2 cm
    inside their support polygon and no sphere enters the floor (`Target.on_floor`,
    `.balance`, `.no_contact`), so that a far reach bends the hips and moves the pelvis back
    as a person does. `standing=False` holds the pelvis fixed in space (the spine alone
    bends). Constraints among `targets` (`Target.no_contact`, `.on_floor`, `.balance`) hold
    in every phase. The limbs' phase starts from the closed-form limb start (the elbow or knee
    from the distance, the swivel from `init`; `_limb_start`), the trunk's from the limbs'
    closest reach; each phase then tries up to `starts - 1` further starts, each in rounds
    of a few steps, until every target is reached; a target out of a phase's reach spends
    one start. Then the standard orientation is restored
    (`standard_orientation`): twists no target depends on return to the standard
    orientation, joints unchanged. An unreachable target gives the closest reach with
    `reached` False; a solve that misses is a status, never an exception or a NaN.

    Args:
        body: the body.
        targets: `Target.position(...)`, `Target.axis_direction(...)`, `Target.frame(...)`,
            and constraints `Target.no_contact(...)`, `.on_floor(...)`, `.balance(...)`.
        init: the starting pose (default: the standard position).
        spine, free_root, segments: which unknowns exist (above).
        standing: the trunk's phase stands on the feet (above).
        starts: the most starts per phase (>= 1).
        standard_orientation: apply the post-projection.
        max_steps: solver steps per start (>= 1), in rounds of `_attempt.ROUND_STEPS`.
        tol_position, tol_angle: what counts as reached (m, rad; > 0).

    Returns:
        `ReachResult`: the pose; per position or axis target `reached`, `residuals`,
        `valid`, `beyond`; per constraint kind its `violation`; the `status` (a
        `ReachStatus`) and the solver `steps` over all attempts.

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
    goals = [t for t in flat if not is_constraint(t)]
    if not goals:
        raise ValueError("solve_reach: give a position or axis target besides the constraints")
    ts, order = resolve_targets(body, goals)
    default_init = init is None
    init = body.rest_pose() if default_init else init
    stand = standing and not free_root and segments is None
    phase_targets = constrained_targets(body, ts, flat, init, stand, default_init)
    layouts = phase_layouts(
        body, phase_targets, spine=spine, free_root=free_root, segments=segments, stand=stand
    )
    dtype = jnp.result_type(float)
    tols = (_scalar(tol_position, dtype), _scalar(tol_angle, dtype))
    final, ts = layouts[-1], phase_targets[-1]
    project = bool(standard_orientation and needs_projection(body, final, ts.constraints))
    settings = (int(starts), int(max_steps), tols)
    traced = is_traced(body, init, phase_targets)
    plans = None if traced else phase_plans(body, layouts, phase_targets)
    if traced:
        best, steps, beyond = solve_traced(body, layouts, init, phase_targets, *settings)
    else:
        rest = default_init
        best, steps, beyond = solve_host(body, layouts, init, phase_targets, *settings, plans, rest)
    back = np.argsort(order)
    if not traced:
        # On the host, every leaf alike: committed device arrays beside host ones would
        # key the conclusion's program differently from call to call, and a Python int
        # would be a static argument (a program per step count).
        best, steps = jax.device_get(best), np.asarray(steps, np.int32)
    if plans is None:
        keep = keep_mask(body, final, ts.constraints) if project else None
        return _conclude_jit(body, keep, True, best, ts, back, beyond, steps, tols, False)
    # The whole tree's conclusion: one program for every effector set of a bucket and
    # every constraint set (the projection's twists and the targets' order as data; the
    # violations after it, `_with_violations`), cut to the targets on the host.
    padded = padded_targets(_with(ts, None))
    n_p, P, A = len(ts.point_index), *targets_rows(ts)
    back = np.where(back < n_p, back, back - n_p + P)
    back = np.concatenate([back, np.setdiff1d(np.arange(P + A), back)])
    beyond = np.concatenate([beyond, np.zeros(P - n_p, bool)])
    keep, flag = keep_mask(body, final, ts.constraints), device_array(project, bool)
    # Whether the trunk bent the spine is data too: a limbs' answer takes a zero spine
    # target that the conclusion ignores, so both answers share its program.
    bent = best.pose.spine_target is not None
    if body.spine is not None and not bent:
        zero = np.zeros(3, np.asarray(best.pose.angles).dtype)
        best = eqx.tree_at(lambda b: b.pose.spine_target, best, zero, is_leaf=is_none)
    bent_data = None if body.spine is None else device_array(bent, bool)  # None: no spine
    args = (best, padded, back, beyond, steps, tols, True, bent_data)
    result = _with_violations(body, _conclude_jit(body, keep, flag, *args), ts.constraints, tols)
    return _cut(result, len(order), bent)


def constrained_targets(
    body: Body,
    ts: TargetSet,
    flat: Sequence[Target],
    init: Pose,
    stand: bool,
    default_init: bool = False,
) -> list[TargetSet]:
    """The target sets of the limbs' phase and the trunk's: the position and axis targets
    with the given constraints, the trunk's with standing's added when `stand`. From the
    standard position (`default_init`) the constraints are remembered per body and
    constraints, as they depend on nothing else."""
    given = [t for t in flat if is_constraint(t)]

    def both() -> tuple:
        extra = standing_targets(body, init) if stand else []
        limbs = resolve_constraints(body, given, init)
        return limbs, resolve_constraints(body, given + extra, init) if extra else limbs

    if default_init and not is_traced(body, [t.height for t in given]):
        limbs, trunk = _DEFAULT.get(body, (stand, tuple(target_key(t) for t in given)), both)
    else:
        limbs, trunk = both()
    return [_with(ts, limbs), _with(ts, trunk)]


# Planted in the standard position (what `forward` of it reads).
_DEFAULT = BodyCache(STANDARD_POSITION, size=64)


def _with(ts: TargetSet, c) -> TargetSet:
    return eqx.tree_at(lambda t: t.constraints, ts, c, is_leaf=is_none)


def _result(
    body, pose, best: Attempt, ts: TargetSet, back, beyond, steps, tols, padded=False
) -> ReachResult:
    """The verdicts of the kept attempt, back in the order the targets were given (`back`:
    each given target's place in `ts`, points first). `padded` (`_tree.padded_targets`):
    `back` then goes on with the pad rows, cut off by the caller."""
    valid = jnp.concatenate(
        [jnp.all(jnp.isfinite(ts.point_xyz), -1), jnp.all(jnp.isfinite(ts.axis_direction), -1)]
    )
    residuals = jnp.where(valid, jnp.concatenate([best.err_p, best.err_a]), 0.0)
    n_a = ts.axis_direction.shape[0]
    beyond = jnp.concatenate([jnp.asarray(beyond, bool), jnp.zeros(n_a, bool)])
    tol_position, tol_angle = tols
    reached = valid & jnp.concatenate([best.err_p <= tol_position, best.err_a <= tol_angle])
    c = ts.constraints
    violation = pose_violations(body, pose, c).astype(residuals.dtype)
    if padded:
        # The pad rows (not finite by construction; a given target is finite on this path)
        # take no part in the status.
        reached, valid = reached | ~valid, jnp.ones_like(valid)
    status = reach_status(reached, valid, beyond, violation <= tol_position)
    return ReachResult(
        pose=pose,
        reached=reached[back],
        residuals=residuals[back],
        valid=valid[back],
        beyond=beyond[back],
        status=status,
        steps=jnp.asarray(steps),
        violation=violation,
        constraint_names=() if c is None else c.kinds,
    )


def _conclude(
    body, keep, project, best, ts, back, beyond, steps, tols, padded, bent=None
) -> ReachResult:
    """The post-projection (keeping the twists of the mask `keep`, where `project`; none
    when `keep` is None) and the result (`_result`), in one compiled call. `bent` (data):
    whether the pose's spine target bends the spine; where not, the target is a stand-in
    and the vertebrae keep the pose's angles."""
    if bent is None:
        pose = finish(body, best.pose, keep, project)
        return _result(body, pose, best, ts, back, beyond, steps, tols, padded)
    target = best.pose.spine_target
    # The vertebrae where the target bends them, as angles (`project_to_standard` does
    # the same for a pose with a target), else as they are.
    angles = jnp.where(bent, spine_as_angles(body, best.pose).angles, best.pose.angles)
    keep = keep | (bent & vertebrae_mask(body))
    pose = finish(body, Pose(position=best.pose.position, angles=angles), keep, project)
    result = _result(body, pose, best, ts, back, beyond, steps, tols, padded)
    return eqx.tree_at(lambda r: r.pose.spine_target, result, target, is_leaf=is_none)


def _with_violations(body: Body, result: ReachResult, c, tols) -> ReachResult:
    """A conclusion's result (host, its targets padded) with the constraints' violations
    of its pose and the status they give (as `_result` gives them)."""
    if c is None:
        return result
    # The pose's spine as angles (the conclusion's vertebrae): `forward`'s program of a
    # pose without a spine target, the set-up's.
    pose = Pose(position=result.pose.position, angles=result.pose.angles)
    violation = np.asarray(pose_violations(body, pose, c), np.asarray(result.residuals).dtype)
    reached, valid, beyond = (np.asarray(a) for a in (result.reached, result.valid, result.beyond))
    status = reach_status(reached, valid, beyond, violation <= float(tols[0]))
    put = jax.device_put
    return dataclasses.replace(
        result, violation=put(violation), status=put(status), constraint_names=c.kinds
    )


def _cut(result: ReachResult, n: int, bent: bool = True) -> ReachResult:
    """The result's per-target arrays cut to the first n (the padded rows dropped on the
    host and put back: no program compiled), and the spine target dropped where the
    spine was not `bent` (`_conclude`)."""
    cut = lambda a: jax.device_put(np.asarray(a)[:n])  # noqa: E731
    if not bent:
        result = eqx.tree_at(lambda r: r.pose.spine_target, result, None)
    return eqx.tree_at(
        lambda r: (r.reached, r.residuals, r.valid, r.beyond),
        result,
        tuple(cut(a) for a in (result.reached, result.residuals, result.valid, result.beyond)),
    )


_conclude_jit = compiled(_conclude)


def reach_status(reached, valid, beyond, kept=None):
    """The `ReachStatus` (int) of problems from their per-target verdicts (..., n) and
    whether each constraint is kept (`kept`, per kind; None or empty: no constraint); over
    the leading axes, in NumPy for host arrays (no program compiled per batch shape), else
    in JAX."""
    xp = np if all(isinstance(a, np.ndarray) for a in (reached, valid, beyond)) else jnp
    ok = xp.all(reached | ~valid, axis=-1)
    has = kept is not None and kept.shape[-1] > 0
    held = xp.all(kept, axis=-1) if has else xp.ones_like(ok)
    # A target beyond every reach pulls hardest on the constraints: it is named first.
    unreachable = xp.any(beyond & ~reached, axis=-1)
    missed = xp.where(
        unreachable,
        ReachStatus.UNREACHABLE,
        xp.where(
            ok,
            ReachStatus.INVALID_TARGET,
            ReachStatus.CONSTRAINED if has else ReachStatus.NOT_REACHED,
        ),
    )
    return xp.where(
        ~held & ~unreachable,
        ReachStatus.CONSTRAINT_VIOLATED,
        xp.where(xp.all(reached, axis=-1), ReachStatus.SUCCESS, missed),
    ).astype(int)


def _scalar(value, dtype) -> Array:
    """A setting as a device scalar of `dtype` (traced settings stay traced)."""
    if isinstance(value, jax.core.Tracer):
        return jnp.asarray(value, dtype)
    return jax.device_put(np.asarray(value, dtype))


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
