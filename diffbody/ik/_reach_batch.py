"""Batch reach: many position-target problems through one compiled, vmapped solve
(docs/design.md, section 6).

Single process: the batch axis of every chunk is sharded over the local devices when there
is more than one (`jax.sharding.Mesh` + `NamedSharding(mesh, PartitionSpec("batch"))`).
Several hosts: call `jax.distributed.initialize()` first, then the same `solve_reach_batch`
in every process with that process's own rows; each process solves its rows on its local
devices (the problems are independent, so no data crosses hosts), and JAX's runtime does the
rest. There is no cluster layer here.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._body import Body, Pose
from .._progress import Progress
from .._spine import spine_angles
from ._attempt import Attempt, attempt, better
from ._phases import beyond_bound, is_none, phase_layouts
from ._post_projection import finish, needs_projection, twists_to_keep
from ._reach import ReachResult, check_settings, reach_status
from ._targets import Target, TargetSet, resolve_targets
from ._unknowns import Layout


def _attempt_rows(body, layout, inits, template: TargetSet, xyz, ks, max_steps, tol_pos, tol_ang):
    """`attempt` vmapped over rows: their start poses, target positions (batch, k, 3) and
    start indices."""

    def one(init, p, k):
        targets = eqx.tree_at(lambda t: t.point_xyz, template, p)
        return attempt(body, layout, init, targets, k, max_steps, tol_pos, tol_ang)

    return jax.vmap(one)(inits, xyz, ks)


def _finish_rows(body, poses, keep):
    """`finish` vmapped over the rows' poses."""
    return jax.vmap(lambda p: finish(body, p, keep))(poses)


# One compiled function per (body structure, layout, chunk size), shared by all chunks,
# passes and starts (the start index is traced) and by all calls with the same shapes.
_attempt_rows_jit = eqx.filter_jit(_attempt_rows)
_finish_rows_jit = eqx.filter_jit(_finish_rows)


def solve_reach_batch(
    body: Body,
    effectors: Sequence[str],
    positions: ArrayLike,
    *,
    init: Pose | None = None,
    chunk_size: int = 4096,
    progress: bool = True,
    devices: Sequence[jax.Device] | None = None,
    spine: bool = True,
    segments: Sequence[str] | None = None,
    starts: int = 8,
    max_steps: int = 30,
    tol_position: float = 1e-3,
) -> ReachResult:
    """Solve many reach problems: row i puts `effectors[j]` at `positions[i, j]`.

    The same problem as `solve_reach` with position targets only, vmapped: the rows go
    through one jit-compiled solve in chunks of `chunk_size` (the last chunk is padded and
    the padding dropped, so every chunk reuses the same compiled function and memory stays
    bounded by one chunk). Each phase makes two passes: every row still missed from its start
    pose, then the rows with a target missed from the other starts, side by side (one row
    per start: under vmap a chunk would run as many starts in turn as its hardest row). Each
    row's result is what `solve_reach` gives it. Rows with a NaN or infinite coordinate are
    flagged per target (`valid` and `reached` False, residual 0) and never raise or leak NaN;
    the other targets of that row are still solved.

    Args:
        body: the body.
        effectors: k joint / feature names or "center_of_gravity".
        positions: (n, k, 3) metres, or (n, 3) for one effector.
        init: the starting pose of every row (default: the standard position).
        chunk_size: rows per compiled call (rounded up to a multiple of the device count).
        progress: print a progress bar to stderr.
        devices: devices to shard each chunk's rows over (default: `jax.local_devices()`;
            sharding is used when there are several). Multi-host: call
            `jax.distributed.initialize()` first, then this in every process with its rows.
        spine, segments, starts, max_steps, tol_position: as in `solve_reach`.

    Returns:
        A `ReachResult` of host (numpy) arrays with a leading batch axis n: `reached`,
        `residuals`, `valid`, `beyond` (n, k), `status`, `steps` (n,), and the poses.

    Raises:
        KeyError: an unknown effector (the message lists the valid ones).
        ValueError: positions of the wrong shape.
    """
    s = _prepare(
        body,
        effectors,
        positions,
        init=init,
        chunk_size=chunk_size,
        progress=progress,
        devices=devices,
        spine=spine,
        segments=segments,
        starts=starts,
        max_steps=max_steps,
        tol_position=tol_position,
    )
    if not len(s.xyz):
        return _empty_result(s)
    best, steps, beyond = _solve_rows(s)
    return _batch_result(_project(s, best), s.xyz, steps, beyond, s.tol_position)


# --- the steps of solve_reach_batch ----------------------------------------------------------
@dataclass(frozen=True)
class _Setup:
    """What the steps of a batch solve share, checked and prepared on the host."""

    body: Body
    xyz: np.ndarray  # (n, k, 3) m
    template: TargetSet  # the targets of one row, its positions to be replaced
    init: Pose
    layouts: list[Layout]  # the phases
    starts: int
    max_steps: int
    tol_position: float  # m, as given
    tols: tuple[Array, Array]  # m, rad: the solver's tolerances
    chunk: int  # rows per compiled call, a multiple of the device count
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
    init = body.rest_pose() if init is None else init
    layouts = phase_layouts(body, template, spine=spine, free_root=False, segments=segments)
    n = xyz.shape[0]
    devices = list(jax.local_devices() if devices is None else devices)
    n_dev = len(devices)
    chunk = max(1, min(int(chunk_size), n))
    chunk = -(-chunk // n_dev) * n_dev  # a multiple of the device count
    if n_dev > 1:
        mesh = jax.sharding.Mesh(np.asarray(devices), ("batch",))
        sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    else:
        sharding = jax.sharding.SingleDeviceSharding(devices[0])
    dtype = jnp.result_type(float)
    tols = (jnp.asarray(tol_position, dtype), jnp.asarray(np.deg2rad(1.0), dtype))
    return _Setup(
        body=body,
        xyz=xyz,
        template=template,
        init=init,
        layouts=layouts,
        starts=starts,
        max_steps=max_steps,
        tol_position=tol_position,
        tols=tols,
        chunk=chunk,
        sharding=sharding,
        progress=progress,
    )


def _in_chunks(s: _Setup, fn, arrays, total: int, label: str):
    """fn over `arrays` (leading axis `total`) in chunks of `s.chunk` rows, each sharded over
    the devices, the last padded with copies of its last row (dropped after); host numpy
    results, with a progress bar."""
    chunk = s.chunk
    bar = Progress(total, s.progress, label)
    parts = []
    for at in range(0, total, chunk):
        part = jax.tree.map(lambda a: a[at : at + chunk], arrays)
        m = min(chunk, total - at)
        if m < chunk:
            part = jax.tree.map(
                lambda a: np.concatenate([a, np.repeat(a[-1:], chunk - m, axis=0)]), part
            )
        part = jax.device_put(jax.tree.map(jnp.asarray, part), s.sharding)
        out = fn(*part)
        parts.append(jax.tree.map(lambda a, m=m: np.asarray(a)[:m], out))
        bar.update(at + m)
    return jax.tree.map(lambda *a: np.concatenate(a), *parts)


def _attempts(s: _Setup, layout: Layout, poses: Pose, xyz, ks, label: str) -> Attempt:
    """One attempt per row (its start pose, positions (k, 3) and start index), in chunks."""

    def fn(p, x, k):
        return _attempt_rows_jit(s.body, layout, p, s.template, x, k, s.max_steps, *s.tols)

    return _in_chunks(s, fn, (poses, xyz, ks), len(ks), label)


def _rows(tree, rows):
    """The given rows of every array of the tree."""
    return jax.tree.map(lambda a: a[rows], tree)


def _empty_result(s: _Setup) -> ReachResult:
    """The result of no rows, its shapes from the abstract evaluation."""
    k = s.xyz.shape[1]
    poses = jax.tree.map(lambda a: jnp.asarray(a)[None], s.init)
    shapes = eqx.filter_eval_shape(
        _attempt_rows,
        s.body,
        s.layouts[-1],
        poses,
        s.template,
        jnp.zeros((1, k, 3)),
        jnp.zeros(1, int),
        s.max_steps,
        *s.tols,
    )
    empty = jax.tree.map(lambda a: np.zeros((0,) + a.shape[1:], a.dtype), shapes)
    return _batch_result(empty, s.xyz, np.zeros(0, int), np.zeros((0, k), bool), s.tol_position)


def _solve_rows(s: _Setup) -> tuple[Attempt, np.ndarray, np.ndarray]:
    """The phases over the rows: a pass of every row still missed from its start pose, then
    `_retry` of those with no bound against them; the next phase (the trunk) takes the rows
    still missed from the limbs' closest reach. Returns the kept attempts, the steps (n,)
    and `beyond` (n, k)."""
    n, k = s.xyz.shape[:2]
    init_np = jax.tree.map(np.asarray, s.init)
    best = None
    steps = np.zeros(n, int)
    beyond = np.zeros((n, k), bool)
    start_poses = jax.tree.map(lambda a: np.repeat(a[None], n, axis=0), init_np)
    todo = np.arange(n)
    for phase, layout in enumerate(s.layouts):
        beyond = beyond_bound(s.body, layout, s.init, s.xyz)
        label = "reach" if phase == 0 else "reach, trunk"
        zeros = np.zeros(len(todo), int)
        a = _attempts(s, layout, _rows(start_poses, todo), s.xyz[todo], zeros, label)
        steps[todo] += a.steps
        if best is not None and best.pose.spine_target is None and a.pose.spine_target is not None:
            best = _with_spine_target(s, best)
        best = a if best is None else _merge(best, todo, a)
        retry = todo[~a.ok & ~beyond[todo].any(-1)]
        if s.starts > 1 and len(retry):
            best, spent = _retry(s, layout, start_poses, retry, best)
            steps[retry] += spent
        todo = np.flatnonzero(~best.ok)
        if not len(todo):
            break
        start_poses = best.pose  # the trunk joins from the limbs' closest reach
    return best, steps, beyond


def _with_spine_target(s: _Setup, best: Attempt) -> Attempt:
    """The limbs' attempts with the spine, left as in init, named as its target, so that
    both phases' poses share one structure."""
    total = np.asarray(spine_angles(s.body, s.body.spine, s.init).sum(0))
    n = len(s.xyz)
    return eqx.tree_at(
        lambda b: b.pose.spine_target, best, np.repeat(total[None], n, 0), is_leaf=is_none
    )


def _retry(
    s: _Setup, layout: Layout, start_poses: Pose, retry: np.ndarray, best: Attempt
) -> tuple[Attempt, np.ndarray]:
    """The further starts of rows `retry`, side by side (one row per start); per row the
    first that reaches (else the closest) replaces `best` where it is better. Returns the
    new best and the steps of each retried row, counted as `solve_reach` counts them: the
    starts tried up to the first that reaches."""
    more = s.starts - 1
    ks = np.tile(np.arange(1, s.starts), len(retry))
    rows = np.repeat(retry, more)
    b = _attempts(s, layout, _rows(start_poses, rows), s.xyz[rows], ks, "retry")
    b_ok = b.ok.reshape(len(retry), more)
    b_cost = b.cost.reshape(len(retry), more)
    pick = np.where(b_ok.any(1), b_ok.argmax(1), b_cost.argmin(1))
    spent = np.cumsum(b.steps.reshape(len(retry), more), axis=1)
    spent = np.where(b_ok.any(1), spent[np.arange(len(retry)), pick], spent[:, -1])
    chosen = _rows(b, np.arange(len(retry)) * more + pick)
    take = better(chosen, _rows(best, retry))
    return _merge(best, retry[take], _rows(chosen, take)), spent


def _project(s: _Setup, best: Attempt) -> Attempt:
    """The rows' poses after the post-projection, when the final phase needs one."""
    final = s.layouts[-1]
    keep = twists_to_keep(s.body, final) if needs_projection(s.body, final) else None
    if keep is None:
        return best
    n = len(s.xyz)
    poses = _in_chunks(s, lambda p: _finish_rows_jit(s.body, p, keep), (best.pose,), n, "project")
    return eqx.tree_at(lambda b: b.pose, best, poses)


def _merge(best: Attempt, rows: np.ndarray, new: Attempt) -> Attempt:
    """A copy of `best` (host arrays) with `rows` replaced by `new`."""

    def put(a, r):
        a = np.array(a, copy=True)
        a[rows] = r
        return a

    return jax.tree.map(put, best, new)


def _batch_result(best: Attempt, xyz: np.ndarray, steps, beyond, tol_position) -> ReachResult:
    """Per-row results as host arrays (no axis targets in a batch)."""
    valid = np.isfinite(xyz).all(-1)
    reached = valid & (best.err_p <= tol_position)
    status = (
        np.asarray(jax.vmap(reach_status)(reached, valid, beyond & valid))
        if len(xyz)
        else np.zeros(0, int)
    )
    return ReachResult(
        pose=best.pose,
        reached=reached,
        residuals=np.where(valid, best.err_p, 0.0),
        valid=valid,
        beyond=beyond & valid,
        status=status,
        steps=np.asarray(steps),
    )
