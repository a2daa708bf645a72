"""Batch reach: many position-target problems through one compiled, vmapped solve
(docs/design.md, section 6). The batch axis of every chunk is sharded over the local devices
when there are several; written to a file as it goes and over processes: `_batch_run`.
"""

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._body import Body, Pose
from .._device_arrays import device_array
from .._programs import compiled
from .._spine import spine_angles
from ..files._targets_file import read_targets
from ..problem._constraints import is_constraint, pose_violations
from ..problem._targets import Target, TargetSet, resolve_targets
from ..problem._unknowns import Layout
from ..runs._batches import bucket, chunk_rows, map_chunks, put_rows, row_sharding, take_rows
from ._attempt import Attempt, Settings, attempt_round, better, phase_steps, round_caps
from ._phases import is_none, phase_layouts, phase_plan, phase_targets_of, uses_limb_start
from ._plans import limb_plans
from ._post_projection import finish, keep_mask, needs_projection
from ._reach import ReachResult, check_settings, constrained_targets, reach_status


def _round_rows(body, layout, inits, template, xyz, x, ks, fresh, cap, settings, plan=None):
    """`attempt_round` vmapped over rows: their start poses (or one `Pose` shared by every
    row: then what depends on it alone, the start's walk and problem, is computed once per
    chunk, not per row), target positions (batch, k, 3), free vectors to go on from, start
    indices and whether each begins its start. `plan`: a limb chain's (`_tree`), shared by
    every row."""

    def one(init, p, x, k, f):
        targets = eqx.tree_at(lambda t: t.point_xyz, template, p)
        return attempt_round(body, layout, init, targets, x, k, f, cap, settings, plan)

    shared = jnp.ndim(inits.position) == 1
    return jax.vmap(one, in_axes=(None if shared else 0, 0, 0, 0, 0))(inits, xyz, x, ks, fresh)


def _finish_rows(body, poses, keep):
    """`finish` vmapped over the rows' poses."""
    return jax.vmap(lambda p: finish(body, p, keep))(poses)


# One compiled function per (body structure, layout, chunk size), shared by all chunks,
# starts, rounds and round caps (the start index and the cap are data).
_round_rows_jit = compiled(_round_rows)
_finish_rows_jit = compiled(_finish_rows)

# Rows per compiled call of the passes over the rows that still miss (further rounds and
# starts, the trunk's phase), when fewer than half a chunk: the few rows left after the
# first round run in chunks their size, not padded to a whole chunk (one more compiled
# shape, for batches larger than this).
RETRY_ROWS = 64


def solve_reach_batch(
    body: Body,
    effectors: Sequence[str],
    positions: ArrayLike | str | os.PathLike,
    *,
    init: Pose | None = None,
    chunk_size: int = 4096,
    progress: bool = True,
    devices: Sequence[jax.Device] | None = None,
    spine: bool = True,
    standing: bool = True,
    constraints: Sequence[Target] = (),
    segments: Sequence[str] | None = None,
    starts: int = 8,
    max_steps: int = 30,
    tol_position: float = 1e-3,
) -> ReachResult:
    """Solve many reach problems: row i puts `effectors[j]` at `positions[i, j]`.

    The same problem as `solve_reach` with position targets only, vmapped: the rows go
    through one jit-compiled solve in chunks of `chunk_size` (the last chunk is padded and
    the padding dropped, so every chunk reuses the same compiled function and memory stays
    bounded by one chunk). Each phase tries its starts in turn, each in rounds
    (`_attempt.ROUND_STEPS`), and every pass takes only the rows still running or missed
    (compacted: under vmap a chunk runs as long as its slowest row). Each row's result is
    what `solve_reach` gives it. Rows with a NaN or infinite coordinate are
    flagged per target (`valid` and `reached` False, residual 0) and never raise or leak NaN;
    the other targets of that row are still solved.

    Args:
        body: the body.
        effectors: k joint / feature names or "center_of_gravity".
        positions: (n, k, 3) metres, or (n, 3) for one effector; or a file of them (CSV
            of x,y,z per effector, a header row optional, or Parquet with pyarrow).
        init: the starting pose of every row (default: the standard position).
        chunk_size: rows per compiled call, or for fewer rows the power of two that holds
            them (rounded up to a multiple of the device count).
        progress: print a progress bar to stderr.
        devices: devices to shard each chunk's rows over (default: `jax.local_devices()`;
            sharding is used when there are several).
        spine, standing, segments, starts, max_steps, tol_position: as in `solve_reach`.
        constraints: `Target.no_contact(...)`, `.on_floor(...)`, `.balance(...)`, held by
            every row (the floor places from `init`).

    Returns:
        A `ReachResult` of host (numpy) arrays with a leading batch axis n: `reached`,
        `residuals`, `valid`, `beyond` (n, k), `status`, `steps` (n,), `violation`
        (n, n_constraints), and the poses. `run_reach_batch` writes them to a file instead,
        as the run goes.

    Raises:
        KeyError: an unknown effector (the message lists the valid ones).
        ValueError: positions of the wrong shape.
    """
    settings = dict(init=init, spine=spine, standing=standing, constraints=constraints)
    settings.update(segments=segments, starts=starts, max_steps=max_steps, devices=devices)
    settings.update(chunk_size=chunk_size, progress=progress, tol_position=tol_position)
    effectors = [effectors] if isinstance(effectors, str) else list(effectors)
    if isinstance(positions, (str, os.PathLike)):  # read whole
        positions = read_targets(positions, len(effectors))
    s = _prepare(body, effectors, positions, **settings)
    if not len(s.xyz):
        return _empty_result(s)
    best, steps, beyond = _solve_rows(s)
    return _batch_result(s, _project(s, best), steps, beyond)


def check_batch(body: Body, effectors: Sequence[str], **settings) -> None:
    """Refuse bad settings of `solve_reach_batch` (as it would) before any row is read."""
    _prepare(body, effectors, np.zeros((1, len(effectors), 3)), **settings)


# --- the steps of solve_reach_batch ----------------------------------------------------------
@dataclass(frozen=True)
class _Setup:
    """What the steps of a batch solve share, checked and prepared on the host."""

    body: Body
    xyz: np.ndarray  # (n, k, 3) m
    templates: list[TargetSet]  # per phase, the targets of one row (positions replaced)
    plans: list  # per phase, its limb chain's layout, plan and padded targets, or None
    closed: list[bool]  # per phase, whether its first start is the closed-form limb start
    init: Pose
    layouts: list[Layout]  # the phases
    starts: int
    max_steps: int
    tol_position: float  # m, as given
    tols: tuple[Array, Array]  # m, rad: the solver's tolerances
    chunk: int  # rows per compiled call, a multiple of the device count
    retry_chunk: int  # rows per compiled call of a pass over fewer than half a chunk
    sharding: jax.sharding.Sharding
    progress: bool


def _prepare(
    body: Body,
    effectors,
    positions,
    *,
    init,
    chunk_size,
    progress,
    devices,
    spine,
    standing,
    constraints,
    segments,
    starts,
    max_steps,
    tol_position,
) -> _Setup:
    """Check the arguments (host) and prepare the solve: positions as (n, k, 3), the
    targets' template, the phases' layouts, the chunk size and the devices' sharding."""
    effectors = [effectors] if isinstance(effectors, str) else list(effectors)
    k = len(effectors)
    xyz = np.asarray(positions, dtype=float)
    if k == 1 and xyz.ndim == 2:
        xyz = xyz[:, None, :]
    if k == 0 or xyz.ndim != 3 or xyz.shape[1:] != (k, 3):
        raise ValueError(
            f"solve_reach_batch: positions must have shape (n, {k}, 3) for {k} effector(s)"
            + (" or (n, 3)" if k == 1 else "")
            + f", got {np.shape(positions)}"
        )
    check_settings(starts=starts, max_steps=max_steps, tol_position=tol_position, tol_angle=1.0)
    template, _ = resolve_targets(body, [Target.position(e, np.zeros(3)) for e in effectors])
    default_init = init is None
    init = body.rest_pose() if default_init else init
    constraints = list(constraints)
    if not all(isinstance(c, Target) and is_constraint(c) for c in constraints):
        raise TypeError(
            "solve_reach_batch: constraints must be Target.no_contact / .on_floor / .balance"
        )
    stand = standing and segments is None
    phase_targets = constrained_targets(body, template, constraints, init, stand, default_init)
    layouts = phase_layouts(
        body, phase_targets, spine=spine, free_root=False, segments=segments, stand=stand
    )
    templates = phase_targets_of(layouts, phase_targets)
    closed = [uses_limb_start(k, templates[0]) for k in range(len(layouts))]
    n = xyz.shape[0]
    devices = list(jax.local_devices() if devices is None else devices)
    # Power-of-two buckets: 17 and 32 rows run one program (a row costs little beside a call).
    chunk = chunk_rows(chunk_size, bucket(n), len(devices))
    dtype = jnp.result_type(float)
    tols = (device_array(tol_position, dtype), device_array(np.deg2rad(1.0), dtype))
    return _Setup(
        body=body,
        xyz=xyz,
        templates=templates,
        plans=limb_plans(body, layouts, templates, closed),
        closed=closed,
        init=init,
        layouts=layouts,
        starts=starts,
        max_steps=max_steps,
        tol_position=tol_position,
        tols=tols,
        chunk=chunk,
        retry_chunk=chunk_rows(min(chunk, RETRY_ROWS), bucket(n), len(devices)),
        sharding=row_sharding(devices),
        progress=progress,
    )


def _round(s: _Setup, phase: int, rows, poses: Pose | None, x, ks, fresh, cap, label):
    """One round of a phase's rows (their start poses, None: all from s.init; free vectors,
    start indices and whether each begins its start), in chunks: the free vectors, whether
    each solve ended, the attempts. A limb chain's phase runs on its program (`_tree`): the
    targets padded to their bucket, the errors cut back to the effectors."""
    layout, template, closed = s.layouts[phase], s.templates[phase], s.closed[phase]
    planned = s.plans[phase]
    xyz = s.xyz[rows]
    plan = None
    if planned is not None:
        layout, plan, template = planned
        closed = True  # the plan says (data): one program either way
        P = template.point_xyz.shape[0]
        xyz = np.concatenate([xyz, np.full((len(rows), P - xyz.shape[1], 3), np.nan)], axis=1)
    cap = np.asarray(cap, np.int32)  # data: every round cap shares one program

    def fn(p, xyz, x, k, f):
        args = (s.body, layout, p, template, xyz, x, k, f, cap, Settings(*s.tols, closed), plan)
        return _round_rows_jit(*args)

    chunk = s.chunk if 2 * len(rows) > s.chunk else s.retry_chunk
    arrays = (xyz, x, ks, fresh)
    opts = dict(chunk=chunk, sharding=s.sharding, progress=s.progress, label=label, unit="solve")
    if poses is None:  # every row starts from s.init
        x, done, a = map_chunks(functools.partial(fn, s.init), arrays, **opts)
    else:
        x, done, a = map_chunks(fn, (poses,) + arrays, **opts)
    if planned is not None:
        errors = (a.err_p[:, : s.xyz.shape[1]], a.err_a[:, :0])
        a = eqx.tree_at(lambda a: (a.err_p, a.err_a), a, errors)
    return x, done, a


def _empty_result(s: _Setup) -> ReachResult:
    """The result of no rows, its shapes from the abstract evaluation."""
    k = s.xyz.shape[1]
    poses = jax.tree.map(lambda a: jnp.asarray(a)[None], s.init)
    layout = s.layouts[-1]
    _, _, shapes = eqx.filter_eval_shape(
        _round_rows,
        s.body,
        layout,
        poses,
        s.templates[-1],
        jnp.zeros((1, k, 3)),
        jnp.zeros((1, layout.n_free), s.tols[0].dtype),
        jnp.zeros(1, int),
        jnp.ones(1, bool),
        s.max_steps,
        Settings(*s.tols),
    )
    empty = jax.tree.map(lambda a: np.zeros((0,) + a.shape[1:], a.dtype), shapes)
    return _batch_result(s, empty, np.zeros(0, int), np.zeros((0, k), bool))


def _solve_rows(s: _Setup) -> tuple[Attempt, np.ndarray, np.ndarray]:
    """The phases over the rows: in each, the starts in turn (`_start`) over the rows that
    still miss, a row out of the phase's reach trying the first start only; the next phase
    (the trunk) takes the rows still missed from the limbs' closest reach. Returns the kept
    attempts, the steps (n,) and `beyond` (n, k)."""
    n, k = s.xyz.shape[:2]
    best = None
    steps = np.zeros(n, int)
    beyond = np.zeros((n, k), bool)
    start_poses = None  # every row from s.init
    todo = np.arange(n)
    for phase, layout in enumerate(s.layouts):
        steps_k = phase_steps(layout, s.max_steps)
        beyond, far, far_caps = phase_plan(s.body, s.layouts, phase, s.init, s.xyz, steps_k)
        far = far.any(-1)
        rows = todo
        for start in range(s.starts):
            left = s.starts - start
            tail = start > 0 and len(rows) * left <= s.retry_chunk
            run = _side_by_side if tail else _start
            a, spent = run(s, layout, phase, start_poses, rows, start, far, far_caps)
            steps[rows] += spent
            if best is not None and best.pose.spine_target is None:
                if a.pose.spine_target is not None:
                    best = _with_spine_target(s, best)
            if best is None:
                best = a
            else:
                take = better(a, take_rows(best, rows))
                best = put_rows(best, rows[take], take_rows(a, take))
            rows = rows[~a.ok & ~far[rows]]
            if tail or not len(rows):
                break
        todo = np.flatnonzero(~best.ok)
        if not len(todo):
            break
        start_poses = best.pose  # the trunk joins from the limbs' closest reach
    return best, steps, beyond


def _start(
    s: _Setup, layout: Layout, phase: int, start_poses: Pose | None, rows, start, far, far_caps
) -> tuple[Attempt, np.ndarray]:
    """Start `start` of rows `rows` in rounds, each round over the rows whose solve goes on
    (a row out of reach: `far_caps`). Returns the attempts and the steps of each row."""
    m = len(rows)
    caps = round_caps(phase_steps(layout, s.max_steps))
    n_free = (layout if s.plans[phase] is None else s.plans[phase][0]).n_free
    x = np.zeros((m, n_free), np.dtype(s.tols[0].dtype))
    spent = np.zeros(m, int)
    fresh = np.ones(m, bool)
    ks = np.broadcast_to(start, (m,)).copy()
    rounds = np.where(far[rows], len(far_caps), len(caps))
    out = None
    going = np.arange(m)
    label = "reach" if phase == 0 and np.all(start == 0) else "reach, further starts"
    for r, cap in enumerate(caps):
        poses = None if start_poses is None else take_rows(start_poses, rows[going])
        g = going
        x_r, done, a = _round(s, phase, rows[g], poses, x[g], ks[g], fresh[g], cap, label)
        x[going], fresh[going] = x_r, False
        spent[going] += a.steps
        out = a if out is None else put_rows(out, going, a)
        going = going[~done & (r + 1 < rounds[going])]
        if not len(going):
            break
    return eqx.tree_at(lambda a: a.steps, out, spent), spent


def _side_by_side(
    s: _Setup, layout: Layout, phase: int, start_poses: Pose | None, rows, start, far, far_caps
) -> tuple[Attempt, np.ndarray]:
    """Starts `start`.. of rows `rows` side by side (one lane per row and start, in rounds),
    for the few rows left: a call's cost barely depends on its rows, so the tail of hard
    rows takes one pass instead of one per start. Per row the first start that reaches
    (else the closest), its steps counted as `_start` in turn counts them: up to that start."""
    left = s.starts - start
    lanes = np.repeat(rows, left)
    ks = np.tile(np.arange(start, s.starts), len(rows))
    a, _ = _start(s, layout, phase, start_poses, lanes, ks, far, far_caps)
    ok, cost = a.ok.reshape(-1, left), a.cost.reshape(-1, left)
    pick = np.where(ok.any(1), ok.argmax(1), cost.argmin(1))
    spent = np.cumsum(a.steps.reshape(-1, left), axis=1)
    spent = spent[np.arange(len(rows)), np.where(ok.any(1), pick, left - 1)]
    chosen = take_rows(a, np.arange(len(rows)) * left + pick)
    return eqx.tree_at(lambda a: a.steps, chosen, spent), spent


def _with_spine_target(s: _Setup, best: Attempt) -> Attempt:
    """The limbs' attempts with the spine, left as in init, named as its target, so that
    both phases' poses share one structure."""
    total = np.asarray(spine_angles(s.body, s.body.spine, s.init).sum(0))
    n = len(s.xyz)
    return eqx.tree_at(
        lambda b: b.pose.spine_target, best, np.repeat(total[None], n, 0), is_leaf=is_none
    )


def _project(s: _Setup, best: Attempt) -> Attempt:
    """The rows' poses after the post-projection, when the final phase needs one."""
    final = s.layouts[-1]
    c = s.templates[-1].constraints
    keep = keep_mask(s.body, final, c) if needs_projection(s.body, final, c) else None
    if keep is None:
        return best
    poses = _over_poses(s, lambda p: _finish_rows_jit(s.body, p, keep), best.pose, "project")
    return eqx.tree_at(lambda b: b.pose, best, poses)


def _over_poses(s: _Setup, fn, poses: Pose, label: str):
    """fn over the rows' poses, in the setup's chunks and sharding."""
    return map_chunks(
        fn,
        (poses,),
        chunk=s.chunk,
        sharding=s.sharding,
        progress=s.progress,
        label=label,
        unit="pose",
    )


def _batch_result(s: _Setup, best: Attempt, steps, beyond) -> ReachResult:
    """Per-row results as host arrays (no axis targets in a batch); each row's constraint
    violations from its pose (`pose_violations`)."""
    xyz, tol_position = s.xyz, s.tol_position
    valid = np.isfinite(xyz).all(-1)
    reached = valid & (best.err_p <= tol_position)
    c = s.templates[-1].constraints
    n_c = 0 if c is None else len(c.kinds)
    violation = np.zeros((len(xyz), n_c))
    if n_c and len(xyz):
        check = lambda p: _violations_jit(s.body, p, c)  # noqa: E731
        violation = np.asarray(_over_poses(s, check, best.pose, "constraints"))
    kept = violation <= tol_position
    status = reach_status(reached, valid, beyond & valid, kept)
    return ReachResult(
        pose=best.pose,
        reached=reached,
        residuals=np.where(valid, best.err_p, 0.0),
        valid=valid,
        beyond=beyond & valid,
        status=status,
        steps=np.asarray(steps),
        violation=violation,
        constraint_names=() if c is None else c.kinds,
    )


_violations_jit = eqx.filter_jit(
    lambda body, poses, c: jax.vmap(lambda p: pose_violations(body, p, c))(poses)
)
