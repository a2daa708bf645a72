"""A reach batch written to a file as it goes (`run_reach_batch`, `diffbody batch`): read a
chunk of targets, solve it, write its postures and then its rows, repeat; resumable after an
interrupt, and spread over processes with `jax.distributed` (docs/design.md, section 6; the
file's layout: `_batch_file`).

A chunk is the unit of work and of writing. Every chunk has `chunk` rows (the last padded
with NaN rows, flagged invalid at once and dropped), so every chunk runs the same compiled
solves and a row's result does not depend on which run, process or resume solved it.
With `jax.process_count()` processes, process p solves the chunks
``range(p * C // N, (p + 1) * C // N)`` of the C chunks, whole chunks in input order, so
the merge is a concatenation.
"""

import hashlib
import itertools
import os
import shutil
import signal
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import numpy as np

from .._progress import Progress
from ..files._pose_file import PoseRecord, load_pose
from ..files._targets_file import scan_targets, target_chunks
from . import _batch_file as bf
from ._batch_postures import merge_postures, write_part
from ._streaming import (
    Interrupted,
    Interrupts,
    append_lines,
    header_text,
    read_results,
    replace_atomically,
)


@dataclass(frozen=True)
class BatchRun:
    """What `run_reach_batch` wrote: the results CSV `out` (one row per target),
    the postures file `poses` beside it, the number of `rows` and of rows whose every
    target was `reached`, and how many rows this call solved (`solved`; fewer than `rows`
    when it resumed an interrupted run, 0 when the run was complete)."""

    out: str
    poses: str
    rows: int
    reached: int
    solved: int

    def load(self) -> PoseRecord:
        """The postures with their status, residuals and targets (`load_pose`)."""
        return load_pose(self.poses)


@dataclass
class _Source:
    """Where the targets come from: a file read a chunk at a time, or an array."""

    name: str
    sha256: str
    total: int
    path: str | None = None
    xyz: np.ndarray | None = None

    def chunks(self, k: int, chunk: int):
        if self.path is not None:
            yield from target_chunks(self.path, k, chunk)
        else:
            for at in range(0, self.total, chunk):
                yield self.xyz[at : at + chunk]


def _source(targets, k: int) -> _Source:
    """Check the targets before any solve: every row of a file (counted and hashed), or an
    array's shape."""
    if isinstance(targets, (str, os.PathLike)):
        path = os.fspath(targets)
        sha256, total = scan_targets(path, k)
        return _Source(path, sha256, total, path=path)
    xyz = np.asarray(targets, float)
    if xyz.ndim == 2 and k == 1:
        xyz = xyz[:, None]
    if xyz.ndim != 3 or xyz.shape[1:] != (k, 3) or not len(xyz):
        raise ValueError(f"positions: expected (n, {k}, 3) with n >= 1, got shape {xyz.shape}")
    digest = hashlib.sha256(str(xyz.shape).encode())
    digest.update(np.ascontiguousarray(xyz).tobytes())
    return _Source("(array)", digest.hexdigest(), len(xyz), xyz=xyz)


def stream_reach_batch(
    solve,
    body,
    effectors: Sequence[str],
    targets,
    out: str | os.PathLike,
    settings: dict,
    *,
    resume: bool,
    chunk_size: int,
    progress: bool,
    names: dict[str, str] = bf.KEYWORDS,
    resume_option: str = "resume=True",
) -> BatchRun:
    """`run_reach_batch`: see there. `solve(xyz, chunk)` is one chunk's `ReachResult` (host
    arrays), `settings` what decides a row (`bf.header_fields`). `names` and
    `resume_option` word the refusals as the caller's user gave the settings (the command
    line's options)."""
    out, effectors = os.fspath(out), list(effectors)
    source = _source(targets, len(effectors))
    if source.path is not None and os.path.exists(out) and os.path.samefile(out, source.path):
        raise ValueError(f"{out}: is the targets file; give another file name for the results")
    chunk = min(int(chunk_size), source.total)
    fields = bf.header_fields(
        source.name, source.sha256, source.total, body, effectors, chunk, settings
    )
    count, process = jax.process_count(), jax.process_index()
    n_chunks = -(-source.total // chunk)
    share = range(process * n_chunks // count, (process + 1) * n_chunks // count)
    if resume and bf.is_complete(out, source.total):
        bf.check_header(read_results(out), fields, names, out, resume_option)
        print(f"resuming {out} after {source.total} of {source.total} rows: it is complete")
        return BatchRun(out, bf.poses_path(out), source.total, bf.rows_reached(out, effectors), 0)
    path = bf.process_path(out, process, count)
    size = min(share.stop * chunk, source.total) - share.start * chunk
    stop = None
    with Interrupts() as signals:
        try:
            solved = _run_share(
                body, effectors, source, path, fields, names, share, chunk, resume,
                resume_option, progress, solve, signals,
            )  # fmt: skip
        except Interrupted as e:
            stop = e
    # The signal handlers are back: a second Ctrl-C while the processes meet is the caller's.
    try:
        _finish_processes(out, fields, source.total, chunk, n_chunks, body, effectors)
    except KeyboardInterrupt as e:  # the share is written; the merge goes on with --resume
        if stop is None:
            signum = e.signum if isinstance(e, Interrupted) else signal.SIGINT
            stop = Interrupted(signum, size, size, path)
    if stop is not None:
        raise stop
    if count > 1 and not bf.is_complete(out, source.total):
        # Another process was stopped before its share was done: nothing was merged, and
        # this process's finished share waits in its part for every process's --resume.
        raise Interrupted(signal.SIGINT, size, size, path)
    reached = bf.rows_reached(out, effectors)
    return BatchRun(out, bf.poses_path(out), source.total, reached, solved)


def _run_share(
    body, effectors, source, path, fields, names, share, chunk, resume, resume_option,
    progress, solve, signals,
) -> int:  # fmt: skip
    """Solve this process's chunks not yet in `path` and append them; the rows solved. An
    interrupt (or a KeyboardInterrupt from inside a solve) is raised as `Interrupted`
    telling how far the share got."""
    first = share.start * chunk
    size = min(share.stop * chunk, source.total) - first
    parts = bf.parts_path(bf.out_of(path))
    done, begun, bar = 0, None, Progress(0, False)
    try:
        with signals.held():
            if resume and os.path.exists(path):
                done = bf.resume_point(
                    path, fields, names, share, chunk, source.total, resume_option
                )
                print(f"resuming {path} after {done} of {size} rows")
            else:
                if resume:
                    print(f"{resume_option}: no {path} yet; starting from the first row")
                bf.remove_parts(parts, share)
                if jax.process_index() == 0:
                    bf.remove_file(bf.poses_path(bf.out_of(path)))
                columns = bf.columns(effectors)
                replace_atomically(path, header_text(_with_process(fields, share, chunk), columns))
            begun = done
        bar = Progress(size, progress, "reach", "solve")
        bar.update(done)
        for index, xyz in enumerate(source.chunks(len(effectors), chunk)):
            at = index * chunk
            if index not in share or at - first < done:
                continue
            result = _solve_chunk(solve, xyz, chunk)
            text = bf.rows_text(result, at)
            with signals.held():  # the chunk's postures, then its rows: a row has its posture
                write_part(parts, index, body, result, xyz, effectors)
                append_lines(path, text)
                done = at - first + len(xyz)
            bar.update(done)
    except KeyboardInterrupt as e:  # Interrupted, or a SIGINT seen inside a JAX call
        if bar.bar is not None:
            bar.bar.close()
        signum = e.signum if isinstance(e, Interrupted) else 2
        raise Interrupted(signum, done, size, path if begun is not None else None) from None
    return done - begun


def _with_process(fields, share: range, chunk: int):
    """A process's part names its share of the rows in its header; the one process's file
    is the whole and says nothing of processes."""
    if jax.process_count() == 1:
        return fields
    total = int(dict(fields)["rows"])
    rows = f"{share.start * chunk}-{min(share.stop * chunk, total) - 1}"
    line = ("process", f"{jax.process_index()} of {jax.process_count()} (rows {rows})")
    return fields[:-1] + [line] + fields[-1:]


def _solve_chunk(solve, xyz: np.ndarray, chunk: int):
    """One chunk's `ReachResult` (host arrays, one row per target row)."""
    m, k = xyz.shape[:2]
    # The last chunk is padded to the others' size with NaN rows, so that every chunk runs
    # the same compiled solves; a NaN row is flagged invalid at once and costs no further
    # starts. The padding is dropped.
    padded = np.concatenate([xyz, np.full((chunk - m, k, 3), np.nan)]) if m < chunk else xyz
    return jax.tree.map(lambda a: np.asarray(a)[:m], solve(padded, chunk))


def _finish_processes(out, fields, total, chunk, n_chunks, body, effectors) -> None:
    """Once every process is done (or stopped): process 0 merges the processes' rows into
    `out` and the chunks' postures into the postures file, where every chunk is there. The
    others wait for it, so that each returns with the whole written."""
    count = jax.process_count()
    if count > 1:
        run = next(_RUNS)
        _wait_for_every_process(f"diffbody-batch-{run}-written")
    if jax.process_index() == 0:
        _merge(out, fields, total, chunk, n_chunks, body, effectors)
    if count > 1:
        _wait_for_every_process(f"diffbody-batch-{run}-merged")


_RUNS = itertools.count()  # the streamed batches of this process: their barriers' names
WAIT_MS = 7 * 24 * 3600 * 1000  # a week: the shares may finish hours apart


def _wait_for_every_process(name: str) -> None:
    """A barrier of the processes through JAX's coordination service, as JAX's own
    checkpointing waits: no device collective (gloo's context times out after 30 s, when
    shares finish minutes apart) and a time limit of a week."""
    from jax._src import distributed

    distributed.global_state.client.wait_at_barrier(name, WAIT_MS)


def _merge(out, fields, total, chunk, n_chunks, body, effectors) -> None:
    count = jax.process_count()
    paths = [bf.process_path(out, p, count) for p in range(count)]
    parts = bf.parts_path(out)
    if not all(os.path.exists(bf.part_path(parts, i)) for i in range(n_chunks)):
        return  # a process was stopped: its part goes on with --resume
    if count > 1:
        have = [read_results(p) for p in paths]
        if sum(len(h.ends) for h in have) != total:
            return
        tmp = f"{out}.partial"
        with open(tmp, "wb") as f:
            f.write(header_text(fields, bf.columns(effectors)).encode())
            for h in have:
                with open(h.path, "rb") as part:
                    part.seek(h.start)
                    shutil.copyfileobj(part, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, out)
    merge_postures(parts, n_chunks, bf.poses_path(out), body, effectors)
    shutil.rmtree(parts)
    for p in paths:
        if p != out:
            os.remove(p)
