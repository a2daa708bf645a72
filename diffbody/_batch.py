"""Batch reach: many position-target problems through one compiled, vmapped solve.

Single process: the batch axis of every chunk is sharded over the local devices when there
is more than one (`jax.sharding.Mesh` + `NamedSharding(mesh, PartitionSpec("batch"))`).
Several hosts: call `jax.distributed.initialize()` first, then the same `solve_reach_batch`
in every process with that process's own rows; each process solves its rows on its local
devices (the problems are independent, so no data crosses hosts), and JAX's runtime does the
rest. There is no cluster layer here.
"""

import math
import sys
import time
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._body import Body, Pose
from ._reach import ReachResult, Target, TargetSet, _solve, make_problem, resolve_targets


def _solve_rows(problem, template: TargetSet, xyz, max_steps, tol_pos, tol_angle, first, starts):
    """`_solve` vmapped over the targets' positions (xyz: (batch, k, 3))."""

    def one(p):
        targets = eqx.tree_at(lambda t: t.point_xyz, template, p)
        return _solve(problem, targets, max_steps, tol_pos, tol_angle, starts, True, first)

    return jax.vmap(one)(xyz)


# One compiled function per (body structure, k, chunk size, settings), shared by all chunks,
# both passes (the starts are traced) and all calls with the same shapes.
_solve_rows_jit = eqx.filter_jit(_solve_rows)


def _duration(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    h, r = divmod(s, 3600)
    m, s = divmod(r, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"


class _Progress:
    """A one-line progress bar on stderr: solves done / total, rate, ETA."""

    def __init__(self, total: int, enabled: bool, label: str = "reach", width: int = 30):
        self.total, self.enabled, self.label, self.width = total, enabled, label, width
        self.t0 = time.perf_counter()

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.t0
        rate = done / elapsed if elapsed > 0 else float("nan")
        eta = (self.total - done) / rate if rate > 0 else float("inf")
        fill = int(self.width * done / max(self.total, 1))
        bar = "#" * fill + "." * (self.width - fill)
        end = "\n" if done >= self.total else ""
        sys.stderr.write(
            f"\r{self.label} [{bar}] {done}/{self.total} solves, {rate:.3g}/s, "
            f"ETA {_duration(eta)}   {end}"
        )
        sys.stderr.flush()


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
    template, _ = resolve_targets(body, [Target.position(e, np.zeros(3)) for e in effectors])
    problem = make_problem(body, template, init, spine=spine, segments=segments)
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

    def solve(rows: np.ndarray, chunk: int, first: int, last: int, label: str) -> ReachResult:
        """Rows through the compiled solve in chunks (the last one padded with copies of
        its last row, dropped after), from starts first, ..., last - 1 (traced: one
        compiled function for both passes)."""
        first, last = jnp.asarray(first), jnp.asarray(last)
        settings = jnp.asarray(tol_position), jnp.asarray(0.0)
        bar = _Progress(len(rows), progress, label)
        parts = []
        for at in range(0, len(rows), chunk):
            part = rows[at : at + chunk]
            m = part.shape[0]
            if m < chunk:
                part = np.concatenate([part, np.repeat(part[-1:], chunk - m, axis=0)])
            part = jax.device_put(jnp.asarray(part), sharding)
            out = _solve_rows_jit(problem, template, part, max_steps, *settings, first, last)
            parts.append(jax.tree.map(lambda a, m=m: np.asarray(a)[:m], out))
            bar.update(at + m)
        return jax.tree.map(lambda *a: np.concatenate(a), *parts)

    if n == 0:  # shapes from the abstract evaluation
        shapes = eqx.filter_eval_shape(
            _solve_rows, problem, template, jnp.zeros((1, k, 3)), max_steps, tol_position, 0.0, 0, 1
        )
        return jax.tree.map(lambda s: np.zeros((0,) + s.shape[1:], s.dtype), shapes)
    # Two passes: every row from the initial posture (most are reached there), then the
    # rest from the other starts, in smaller chunks (a power of two, at least an eighth of
    # a chunk: a few compiled shapes at most). Under vmap a chunk runs as many starts as
    # its hardest row, so the hard rows are solved apart.
    out = solve(xyz, chunk, 0, 1, "reach")
    todo = np.flatnonzero(np.any(out.valid & ~out.reached, axis=1))
    if starts > 1 and len(todo):
        small = max(chunk // 8, 1 << (len(todo) - 1).bit_length())
        small = -(-min(small, chunk) // n_dev) * n_dev
        retry = solve(xyz[todo], small, 1, starts, "retry")
        cost = np.sum(np.where(out.valid, out.residuals, 0.0) ** 2, axis=1)
        cost_retry = np.sum(np.where(retry.valid, retry.residuals, 0.0) ** 2, axis=1)
        take = np.all(retry.reached | ~retry.valid, axis=1) | (cost_retry < cost[todo])
        steps = out.steps[todo] + retry.steps
        rows = todo[take]
        out = jax.tree.map(lambda a, r: _put(a, rows, r[take]), out, retry)
        out = eqx.tree_at(lambda o: o.steps, out, _put(out.steps, todo, steps))
    return out


def _put(a: np.ndarray, rows: np.ndarray, values: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[rows] = values
    return a
