"""The `diffbody batch` command: every row of a file of targets reached, one result row each
in a CSV written as the run goes (the run: diffbody/runs/_batch_run.py; the file's layout:
diffbody/runs/_batch_file.py).

The targets are read a chunk of rows at a time (`--chunk-size`); each chunk is solved, its
postures written, then its rows appended to the results CSV in one write, flushed and
fsynced. SIGINT or SIGTERM drops the chunk in flight, keeps every finished one and exits
130 or 143; `--resume` goes on from the last finished chunk, refusing a changed input, body
or setting. Several processes (`jax.distributed`: `--coordinator`, `--num-processes`,
`--process-id`, or found by JAX on a SLURM or Open MPI cluster) each solve a share of the
chunks; process 0 merges the shares in input order.

The results CSV begins with `#` lines (``# key: value``), then the column names, then one
row per target. Read it with ``csv.DictReader(line for line in f if not
line.startswith("#"))`` or ``pandas.read_csv(path, comment="#")``.
"""

import os
import sys

from ._args import (
    add_body_args,
    add_solver_args,
    body_from_args,
    check_names,
    check_output,
    check_segments,
    non_negative_int,
    positive_int,
)

# What the header's settings are called on this command line, for --resume's refusals.
OPTIONS = {
    "effectors": "--effector",
    "segments": "--segments",
    "spine": "the spine (--no-spine)",
    "starts": "--starts",
    "chunk-size": "--chunk-size",
    "standing": "standing",
    "constraints": "the constraints",
    "start-pose": "the start pose",
    "max-steps": "the solver's steps",
    "tol-position": "the position tolerance",
    "float": "the float precision (JAX_ENABLE_X64)",
}

# Environment variables of the cluster launchers whose processes `jax.distributed.initialize()`
# finds on its own, each giving the number of processes.
CLUSTERS = {"SLURM_NTASKS": "SLURM", "OMPI_COMM_WORLD_SIZE": "Open MPI"}


def add_batch_command(sub) -> None:
    """Add the `batch` subcommand to the `diffbody` command line's subparsers."""
    p = sub.add_parser(
        "batch",
        help="reach every row of a file of targets (x,y,z per effector)",
        description="Solves every row, a chunk at a time, appending each finished chunk to "
        "--out: an interrupted run keeps what it solved and goes on with --resume. Over "
        "several processes or machines through JAX's multi-process runtime: give each "
        "process --coordinator, --num-processes and --process-id (under SLURM or Open MPI "
        "nothing needs to be given).",
    )
    add_body_args(p)
    p.add_argument(
        "targets",
        help="CSV of x,y,z per effector in order (header optional), or Parquet (needs pyarrow)",
    )
    p.add_argument("--effector", action="append", required=True, help="repeat for several")
    p.add_argument(
        "--out",
        default="results.csv",
        help="CSV to write (default results.csv); the postures go beside it (results.poses.npz)",
    )
    p.add_argument("--chunk-size", type=positive_int, default=4096, help="rows per compiled call")
    p.add_argument(
        "--resume",
        action="store_true",
        help="go on with an interrupted run's --out (same targets, body and settings) "
        "from its last finished chunk, instead of starting over",
    )
    add_solver_args(p)
    many = p.add_argument_group("several processes (jax.distributed)")
    many.add_argument("--coordinator", default=None, help="HOST:PORT of process 0")
    many.add_argument("--num-processes", type=positive_int, default=None)
    many.add_argument("--process-id", type=non_negative_int, default=None)
    p.set_defaults(run=_batch)


def start_processes(args) -> str | None:
    """Join the other processes through `jax.distributed.initialize`, before anything of JAX
    runs: with --coordinator/--num-processes/--process-id, or with none of them on a cluster
    JAX finds on its own. None (one process) or a line saying which process this is."""
    import jax

    given = [args.coordinator, args.num_processes, args.process_id]
    found = [name for var, name in CLUSTERS.items() if int(os.environ.get(var, "1")) > 1]
    if all(v is None for v in given) and not found:
        return None
    if any(v is None for v in given) and not all(v is None for v in given):
        raise ValueError(
            "--coordinator, --num-processes and --process-id go together: give all three, "
            "or none on a cluster JAX finds itself (SLURM, Open MPI)"
        )
    if args.process_id is not None and args.process_id >= args.num_processes:
        raise ValueError(
            f"--process-id {args.process_id}: processes are numbered 0 to {args.num_processes - 1}"
        )
    if args.coordinator is None:
        jax.distributed.initialize()
    else:
        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    where = f" ({found[0]})" if found else ""
    return f"process {jax.process_index()} of {jax.process_count()}{where}"


def _batch(args) -> int:
    from ..runs._streaming import Interrupted, Interrupts

    check_output("--out", args.out)
    # The run stops cleanly on either signal in every phase, not only while it solves (its
    # own handlers): SIGTERM too while the processes join, the targets are checked, the
    # processes meet and the rows are merged.
    with Interrupts():
        try:
            run = _stream(args)
        except KeyboardInterrupt as e:  # Interrupted, or a SIGINT seen inside a JAX call
            e = e if isinstance(e, Interrupted) else Interrupted(2)
            if e.out is None:
                message = f"interrupted before {args.out} was begun; nothing written"
            elif e.done == e.total and e.out != args.out:
                message = (
                    f"{e.out} holds this process's {e.total} rows; another process stopped "
                    "before its share was done, so nothing was merged; rerun every process "
                    "with --resume"
                )
            else:
                message = f"interrupted after {e.done} of {e.total} rows; {e.out} holds them; "
                message += "rerun with --resume"
            print(message, file=sys.stderr)
            return e.code
    print(f"{run.reached} of {run.rows} rows reached; wrote {run.out} and {run.poses} (postures)")
    return 0


def _stream(args):
    """The run, from joining the other processes to the merged files."""
    from ..ik._reach_run import batch_settings, chunk_solver
    from ..runs._batch_run import stream_reach_batch

    processes = start_processes(args)
    if processes:
        print(processes)
    body = body_from_args(args)
    check_names(body, args.effector, args.segments)
    note = check_segments(body, args.effector, args.segments)
    if note:
        print(note)
    settings = batch_settings(spine=not args.no_spine, segments=args.segments, starts=args.starts)
    return stream_reach_batch(
        chunk_solver(body, args.effector, None, settings),
        body,
        args.effector,
        args.targets,
        args.out,
        settings,
        resume=args.resume,
        chunk_size=args.chunk_size,
        progress=True,
        names=OPTIONS,
        resume_option="--resume",
    )
