"""Batch reach: many position-target problems through one compiled, vmapped solve
(docs/design.md, section 6). The batch axis of every chunk is sharded over the local devices
when there are several; written to a file as it goes and over processes: `_batch_run`.
"""

import dataclasses
import functools
import os
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._body import Body, Pose
from .._programs import compiled
from .._spine import spine_angles
from ..files._targets_file import read_targets
from ..problem._constraints import pose_violations
from ..problem._targets import Target
from ..problem._tree import padded_targets
from ..problem._unknowns import Layout
from ..runs._batches import map_chunks, put_rows, take_rows
from ._attempt import Attempt, Settings, attempt_round, better, phase_steps, round_caps
from ._batch_setup import Setup, prepare
from ._limb_groups import LimbGroup, joined, limb_groups
from ._phases import is_none, phase_plan
from ._post_projection import finish, keep_mask, needs_projection
from ._reach import ReachResult, reach_status


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


def _round_shared(body, layout, init, template, xyz, x, ks, fresh, cap, settings, plan=None):
    """`_round_rows` from one start pose shared by every row."""
    return _round_rows(body, layout, init, template, xyz, x, ks, fresh, cap, settings, plan)


def _finish_rows(body, poses, keep):
    """`finish` vmapped over the rows' poses."""
    return jax.vmap(lambda p: finish(body, p, keep))(poses)


def _violations_rows(body, poses, constraints):
    """`pose_violations` vmapped over the rows' poses."""
    return jax.vmap(lambda p: pose_violations(body, p, constraints))(poses)


# One compiled function per (body structure, layout, chunk size), shared by all chunks,
# starts, rounds and round caps (the start index and the cap are data); every chunk size
# is traced once (the rows' axis symbolic: `_programs.compiled`).
_round_rows_jit = compiled(_round_rows, rows=(2, 4, 5, 6, 7))
_round_shared_jit = compiled(_round_shared, rows=(4, 5, 6, 7))
_finish_rows_jit = compiled(_finish_rows, rows=(1,))
_violations_jit = compiled(_violations_rows, rows=(1,))


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
    s = prepare(body, effectors, positions, **settings)
    if not len(s.xyz):
        return _empty_result(s)
    best, steps, beyond = _solve_rows(s)
    return _batch_result(s, _project(s, best), steps, beyond)


# --- the steps of solve_reach_batch ----------------------------------------------------------
def _round(s: Setup, phase: int, rows, poses: Pose | None, x, ks, fresh, cap, label):
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

    def fn(p, xyz, x, k, f, program=_round_rows_jit):
        args = (s.body, layout, p, template, xyz, x, k, f, cap, Settings(*s.tols, closed), plan)
        return program(*args)

    chunk = s.chunk if 2 * len(rows) > s.chunk else s.retry_chunk
    arrays = (xyz, x, ks, fresh)
    opts = dict(chunk=chunk, sharding=s.sharding, progress=s.progress, label=label, unit="solve")
    if poses is None:  # every row starts from s.init
        shared = functools.partial(fn, s.init, program=_round_shared_jit)
        x, done, a = map_chunks(shared, arrays, **opts)
    else:
        x, done, a = map_chunks(fn, (poses,) + arrays, **opts)
    if planned is not None:
        errors = (a.err_p[:, : s.xyz.shape[1]], a.err_a[:, :0])
        a = eqx.tree_at(lambda a: (a.err_p, a.err_a), a, errors)
    return x, done, a


def _empty_result(s: Setup) -> ReachResult:
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


def _solve_rows(s: Setup) -> tuple[Attempt, np.ndarray, np.ndarray]:
    """The phases over the rows: in each (`_phase`), the starts in turn over the rows that
    still miss; the next phase (the trunk) takes the rows still missed from the limbs'
    closest reach. A limbs' phase on several limbs runs each limb's targets on its own limb
    chain (`_limb_groups`). Returns the kept attempts, the steps (n,) and `beyond` (n, k)."""
    n, k = s.xyz.shape[:2]
    best, steps = None, np.zeros(n, int)
    start_poses = None  # every row from s.init
    todo = np.arange(n)
    for phase in range(len(s.layouts)):
        groups = None
        if phase == 0 and s.plans[0] is None and s.body.root_joint == s.body.default_root_joint:
            groups = limb_groups(s.body, s.layouts[0], s.templates[0], s.closed[0])
        if groups is None:
            best, spent, beyond = _phase(s, phase, start_poses, todo, best)
        else:
            subs = [_limb_setup(s, g) for g in groups]
            tried = [_phase(sub, 0, None, todo, None) for sub in subs]
            best = joined(s.init, s.templates[0], groups, [t[0] for t in tried], put=np.asarray)
            spent = sum(t[1] for t in tried)
            beyond = np.zeros((n, k), bool)
            for g, t in zip(groups, tried):
                beyond[:, g.points] = t[2]
        steps += spent
        todo = np.flatnonzero(~best.ok)
        if not len(todo):
            break
        start_poses = best.pose  # the trunk joins from the limbs' closest reach
    return best, steps, beyond


def _limb_setup(s: Setup, g: LimbGroup) -> Setup:
    """The batch of one limb's targets in the limbs' phase, on its limb chain."""
    limb, plan = g.planned
    return dataclasses.replace(
        s,
        xyz=s.xyz[:, g.points],
        templates=[g.targets],
        plans=[(limb, plan, padded_targets(g.targets, limb=True))],
        closed=s.closed[:1],
        layouts=[g.layout],
    )


def _phase(s: Setup, phase: int, start_poses, todo, best):
    """One phase over the rows `todo`: its starts in turn (`_start`, or side by side for
    the last few rows) over the rows that still miss, a row out of the phase's reach trying
    the first start only. Returns the kept attempts (with `best`'s other rows), the steps
    (n,) and `beyond` (n, k)."""
    steps = np.zeros(len(s.xyz), int)
    layout = s.layouts[phase]
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
    return best, steps, beyond


def _start(
    s: Setup, layout: Layout, phase: int, start_poses: Pose | None, rows, start, far, far_caps
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
    s: Setup, layout: Layout, phase: int, start_poses: Pose | None, rows, start, far, far_caps
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


def _with_spine_target(s: Setup, best: Attempt) -> Attempt:
    """The limbs' attempts with the spine, left as in init, named as its target, so that
    both phases' poses share one structure."""
    total = np.asarray(spine_angles(s.body, s.body.spine, s.init).sum(0))
    n = len(s.xyz)
    return eqx.tree_at(
        lambda b: b.pose.spine_target, best, np.repeat(total[None], n, 0), is_leaf=is_none
    )


def _project(s: Setup, best: Attempt) -> Attempt:
    """The rows' poses after the post-projection, when the final phase needs one."""
    final = s.layouts[-1]
    c = s.templates[-1].constraints
    keep = keep_mask(s.body, final, c) if needs_projection(s.body, final, c) else None
    if keep is None:
        return best
    poses = _over_poses(s, lambda p: _finish_rows_jit(s.body, p, keep), best.pose, "project")
    return eqx.tree_at(lambda b: b.pose, best, poses)


def _over_poses(s: Setup, fn, poses: Pose, label: str):
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


def _batch_result(s: Setup, best: Attempt, steps, beyond) -> ReachResult:
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
