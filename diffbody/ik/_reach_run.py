"""A reach batch written to a file as it goes (`run_reach_batch`, `diffbody batch`): the
batch of `solve_reach_batch`, through the long-run machinery of `diffbody.runs`."""

import inspect
import os
from collections.abc import Sequence

import jax
from jaxtyping import ArrayLike

from .._body import Body, Pose
from ..problem._targets import Target
from ..runs._batch_run import BatchRun, stream_reach_batch
from ._batch_setup import check_batch
from ._reach_batch import solve_reach_batch


def run_reach_batch(
    body: Body,
    effectors: Sequence[str],
    positions: ArrayLike | str | os.PathLike,
    out: str | os.PathLike,
    *,
    resume: bool = False,
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
) -> BatchRun:
    """`solve_reach_batch`, its rows written to the results CSV `out` as the run goes.

    Chunk by chunk, each written whole, its postures beside it (results.poses.npz); a
    targets file is read a chunk at a time, so memory stays flat in the rows. An interrupt
    keeps every finished chunk (`Interrupted`, a KeyboardInterrupt, says how far). Under
    `jax.distributed` each process solves its share and process 0 merges them.

    Args:
        out: the results CSV (format in docs/design.md, "Long runs").
        resume: go on after the file's last finished chunk; refused (ValueError naming what
            changed) when the input, the body or a setting differs.
        The others: as in `solve_reach_batch`.

    Returns:
        A `BatchRun`: the files written and how many rows were solved and reached.
    """
    effectors = [effectors] if isinstance(effectors, str) else list(effectors)
    settings = batch_settings(
        init=init, spine=spine, standing=standing, constraints=constraints,
        segments=segments, starts=starts, max_steps=max_steps, tol_position=tol_position,
    )  # fmt: skip
    check_batch(  # before a file is begun
        body, effectors, chunk_size=chunk_size, progress=progress, devices=devices, **settings
    )
    solve = chunk_solver(body, effectors, devices, settings)
    return stream_reach_batch(
        solve, body, effectors, positions, out, settings,
        resume=resume, chunk_size=chunk_size, progress=progress,
    )  # fmt: skip


# What decides a row: the results file's header records them, a resumed run checks them.
ROW_SETTINGS = ("init", "spine", "standing", "constraints", "segments", "starts", "max_steps")
ROW_SETTINGS += ("tol_position",)
DEFAULTS = {k: p.default for k, p in inspect.signature(solve_reach_batch).parameters.items()}


def batch_settings(**given) -> dict:
    """The settings that decide a row (`ROW_SETTINGS`), `solve_reach_batch`'s defaults for
    those not given."""
    return {k: given[k] if k in given else DEFAULTS[k] for k in ROW_SETTINGS}


def chunk_solver(body: Body, effectors: list[str], devices, settings: dict):
    """`solve(xyz, chunk)`: one chunk of rows through `solve_reach_batch` (looked up at each
    call, so that a test may stand in for it), quietly."""

    def solve(xyz, chunk: int):
        return solve_reach_batch(
            body, effectors, xyz, chunk_size=chunk, progress=False, devices=devices, **settings
        )

    return solve
