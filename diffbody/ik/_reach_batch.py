"""Batch reach: many position-target problems through one compiled, vmapped solve.

Single process: the batch axis of every chunk is sharded over the local devices when there
is more than one (`jax.sharding.Mesh` + `NamedSharding(mesh, PartitionSpec("batch"))`).
Several hosts: call `jax.distributed.initialize()` first, then the same `solve_reach_batch`
in every process with that process's own rows; each process solves its rows on its local
devices (the problems are independent, so no data crosses hosts), and JAX's runtime does the
rest. There is no cluster layer here.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._body import Body, Pose
from .._progress import Progress
from .._spine import spine_angles
from ._post_projection import needs_projection, twists_to_keep
from ._reach import (
    Attempt,
    ReachResult,
    attempt,
    beyond_bound,
    check_settings,
    finish,
    is_none,
    phase_layouts,
    reach_status,
)
from ._targets import Target, TargetSet, resolve_targets


def _attempt_rows(body, layout, inits, template: TargetSet, xyz, ks, max_steps, tol_pos, tol_ang):
    """`attempt` vmapped over rows: their start poses, target positions (batch, k, 3) and
    start indices."""

    def one(init, p, k):
        targets = eqx.tree_at(lambda t: t.point_xyz, template, p)
        return attempt(body, layout, init, targets, k, max_steps, tol_pos, tol_ang)

    return jax.vmap(one)(inits, xyz, ks)


def _finish_rows(body, poses, keep):
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
    bounded by one chunk). Two passes: every row from `init`, then the rows with a target
    missed from the other starts in turn, in smaller chunks (under vmap a chunk runs as many
    starts as its hardest row). Each row's result is what `solve_reach` gives it. Rows with
    a NaN or infinite coordinate are flagged per target (`valid` and `reached` False,
    residual 0) and never raise or leak NaN; the other targets of that row are still solved.

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
        `residuals`, `valid` (n, k), `status`, `steps` (n,), and the poses.

    Raises:
        KeyError: an unknown effector (the message lists the valid ones).
        ValueError: positions of the wrong shape.
    """
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

    def chunks(fn, arrays, total, label):
        """fn over `arrays` (leading axis total) in chunks, the last padded with copies of
        its last row (dropped after); host numpy results."""
        bar = Progress(total, progress, label)
        parts = []
        for at in range(0, total, chunk):
            part = jax.tree.map(lambda a: a[at : at + chunk], arrays)
            m = min(chunk, total - at)
            if m < chunk:
                part = jax.tree.map(
                    lambda a: np.concatenate([a, np.repeat(a[-1:], chunk - m, axis=0)]), part
                )
            part = jax.device_put(jax.tree.map(jnp.asarray, part), sharding)
            out = fn(*part)
            parts.append(jax.tree.map(lambda a, m=m: np.asarray(a)[:m], out))
            bar.update(at + m)
        return jax.tree.map(lambda *a: np.concatenate(a), *parts)

    def run(layout, poses, rows_xyz, ks, label) -> Attempt:
        def fn(p, x, k):
            return _attempt_rows_jit(body, layout, p, template, x, k, max_steps, *tols)

        return chunks(fn, (poses, rows_xyz, ks), len(ks), label)

    def rows_of(tree, rows):
        return jax.tree.map(lambda a: a[rows], tree)

    if n == 0:  # shapes from the abstract evaluation
        poses = jax.tree.map(lambda a: jnp.asarray(a)[None], init)
        shapes = eqx.filter_eval_shape(
            _attempt_rows,
            body,
            layouts[-1],
            poses,
            template,
            jnp.zeros((1, k, 3)),
            jnp.zeros(1, int),
            max_steps,
            *tols,
        )
        empty = jax.tree.map(lambda s: np.zeros((0,) + s.shape[1:], s.dtype), shapes)
        return _batch_result(empty, xyz, np.zeros(0, int), np.zeros((0, k), bool), tol_position)

    init_np = jax.tree.map(np.asarray, init)
    best = None
    steps = np.zeros(n, int)
    beyond = np.zeros((n, k), bool)
    start_poses = jax.tree.map(lambda a: np.repeat(a[None], n, axis=0), init_np)
    todo = np.arange(n)
    for phase, layout in enumerate(layouts):
        beyond = beyond_bound(body, layout, init, xyz)
        label = "reach" if phase == 0 else "reach, trunk"
        a = run(layout, rows_of(start_poses, todo), xyz[todo], np.zeros(len(todo), int), label)
        steps[todo] += a.steps
        if best is not None and best.pose.spine_target is None and a.pose.spine_target is not None:
            # The limbs' phase leaves the spine as in init: name it as a target, so that
            # both phases' poses share one structure.
            total = np.asarray(spine_angles(body, body.spine, init).sum(0))
            best = eqx.tree_at(
                lambda b: b.pose.spine_target, best, np.repeat(total[None], n, 0), is_leaf=is_none
            )
        best = a if best is None else _merge(best, todo, a)
        # Further starts for the rows that missed with no bound against them, all starts
        # side by side (one row per start), the first that reaches kept.
        retry = todo[~a.ok & ~beyond[todo].any(-1)]
        if starts > 1 and len(retry):
            ks = np.tile(np.arange(1, starts), len(retry))
            rows = np.repeat(retry, starts - 1)
            b = run(layout, rows_of(start_poses, rows), xyz[rows], ks, "retry")
            b_ok = b.ok.reshape(len(retry), starts - 1)
            b_cost = b.cost.reshape(len(retry), starts - 1)
            pick = np.where(b_ok.any(1), b_ok.argmax(1), b_cost.argmin(1))
            # Steps as solve_reach counts them: the starts tried up to the first that reaches.
            spent = np.cumsum(b.steps.reshape(len(retry), starts - 1), axis=1)
            steps[retry] += np.where(b_ok.any(1), spent[np.arange(len(retry)), pick], spent[:, -1])
            chosen = rows_of(b, np.arange(len(retry)) * (starts - 1) + pick)
            current = rows_of(best, retry)
            take = (chosen.ok & ~current.ok) | (
                (chosen.ok == current.ok) & (chosen.cost < current.cost)
            )
            best = _merge(best, retry[take], rows_of(chosen, take))
        todo = np.flatnonzero(~best.ok)
        if not len(todo):
            break
        start_poses = best.pose  # the trunk joins from the limbs' closest reach
    final = layouts[-1]
    keep = twists_to_keep(body, final) if needs_projection(body, final) else None
    if keep is not None:
        poses = chunks(lambda p: _finish_rows_jit(body, p, keep), (best.pose,), n, "project")
        best = eqx.tree_at(lambda b: b.pose, best, poses)
    return _batch_result(best, xyz, steps, beyond, tol_position)


def _merge(best: Attempt, rows: np.ndarray, new: Attempt) -> Attempt:
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
