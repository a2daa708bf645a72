"""Long batches: `diffbody batch` on 10,000, 100,000 and 1,000,000 left-palm targets (the arm
alone moves), each run a process of its own as a user starts it; its rows per second and its
peak memory (the process's maximum resident set), which should not grow with the rows (the
targets are read and the results written a chunk at a time). Then one process against two
on the same machine (`jax.distributed` on localhost, the rows split between them and merged).

Compile time apart: a one-chunk run with an empty compilation cache, then the same again
with the cache filled; every timed run reads the cache (as a repeated command does), so its
time is start-up plus solving. Rows per second are the rows over the whole run's time.

    python benchmarks/batch.py              # about 30 minutes on 2 cores
    python benchmarks/batch.py --quick      # a smoke run
"""

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import goal, start_run
from results import add_arguments, out_dir

ARM = ["--segments", "left_upper_arm", "left_forearm", "left_hand"]
CENTRE = np.array([0.3, 0.2, 1.0])  # m: in front of the left shoulder, within reach mostly
SPREAD = 0.15  # m: targets uniform in a cube of this half-width around CENTRE
SEED = 0
MEMORY_GROWTH = 1.25  # the goal: the largest run's peak memory within this of the smallest's


def write_targets(path: Path, n: int, seed: int = SEED) -> None:
    """n targets as a CSV, written a block at a time (a million rows never in memory)."""
    rng = np.random.default_rng(seed)
    with open(path, "w") as f:
        f.write("x,y,z\n")
        for at in range(0, n, 100_000):
            block = CENTRE + rng.uniform(-SPREAD, SPREAD, (min(100_000, n - at), 3))
            f.write("".join(f"{x:.4f},{y:.4f},{z:.4f}\n" for x, y, z in block))


def command(targets: Path, out: Path, chunk: int, *extra: str) -> list[str]:
    argv = [sys.executable, "-m", "diffbody", "batch", str(targets), "--effector"]
    return argv + ["left_hand.palm", "--out", str(out), "--chunk-size", str(chunk), *ARM, *extra]


def run(argvs: list[list[str]], cache: Path) -> tuple[float, list[int]]:
    """Start the commands together and wait for all: (wall seconds, each one's peak memory
    in bytes). A failure stops the benchmark with its output."""
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu")
    env.pop("DIFFBODY_NO_CACHE", None)
    t0 = time.perf_counter()
    procs = [
        subprocess.Popen(a, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        for a in argvs
    ]
    peaks = []
    for p in procs:
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        output = p.stdout.read().decode(errors="replace")
        if p.returncode != 0:
            raise SystemExit(f"{' '.join(p.args)} failed ({p.returncode}):\n{output[-3000:]}")
        peaks.append(usage.ru_maxrss * 1024)  # Linux: kilobytes
    return time.perf_counter() - t0, peaks


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    parser.add_argument("--chunk-size", type=int, default=4096)
    args = parser.parse_args()
    sizes = [256, 1024] if args.quick else [10_000, 100_000, 1_000_000]
    chunk = 128 if args.quick else args.chunk_size
    two_rows = 512 if args.quick else 100_000
    record = start_run(
        "batch",
        args,
        sizes=sizes,
        chunk_size=chunk,
        two_process_rows=two_rows,
        centre_m=CENTRE.tolist(),
        spread_m=SPREAD,
        seed=SEED,
        segments=ARM[1:],
        starts=8,
    )
    print(f"{record.machine}\n{record.versions}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp, cache = Path(tmp), Path(tmp) / "cache"
        targets = tmp / "targets.csv"
        write_targets(targets, chunk)
        compiles = record.table("compile", ["run of one chunk", "seconds"], "lr")
        if not args.quick:  # a smoke run reads the caller's cache (the test suite's)
            cold, _ = run([command(targets, tmp / "r.csv", chunk)], cache)
            compiles.add(f"{chunk} rows, empty compilation cache", f"{cold:.1f}")
        else:
            cache = Path(os.environ.get("JAX_COMPILATION_CACHE_DIR", cache))
        warm, _ = run([command(targets, tmp / "r.csv", chunk)], cache)
        compiles.add(f"{chunk} rows, the cache filled", f"{warm:.1f}")
        print(f"one chunk of {chunk} rows: {warm:.1f} s with the compilation cache")

        table = record.table("rows", ["rows", "seconds", "rows/s", "peak memory (MB)"], "rrrr")
        peaks = {}
        for n in sizes:
            write_targets(targets, n)
            seconds, (peak,) = run([command(targets, tmp / "r.csv", chunk)], cache)
            peaks[n] = peak
            table.add(f"{n:,}", f"{seconds:.1f}", f"{n / seconds:,.0f}", f"{peak / 1e6:,.0f}")
            print(f"{n:,} rows: {seconds:.1f} s, {n / seconds:,.0f} rows/s, {peak / 1e6:,.0f} MB")

        write_targets(targets, two_rows)
        one, (peak_one,) = run([command(targets, tmp / "one.csv", chunk)], cache)
        processes = record.table(
            "processes", ["processes", "seconds", "rows/s", "peak memory per process (MB)"], "lrrr"
        )
        processes.add("1", f"{one:.1f}", f"{two_rows / one:,.0f}", f"{peak_one / 1e6:,.0f}")
        # Twice: process 1's device differs from a lone process's, so its first run compiles
        # (the cache keys name the device); the second reads what the first kept.
        for when in ("first run", "again"):
            address = f"localhost:{free_port()}"
            many = ["--coordinator", address, "--num-processes", "2"]
            argvs = [
                command(targets, tmp / "two.csv", chunk, *many, "--process-id", str(i))
                for i in (0, 1)
            ]
            two, peaks_two = run(argvs, cache)
            processes.add(
                f"2, {when}",
                f"{two:.1f}",
                f"{two_rows / two:,.0f}",
                " / ".join(f"{p / 1e6:,.0f}" for p in peaks_two),
            )
            same = _rows(tmp / "one.csv") == _rows(tmp / "two.csv")
            print(
                f"{two_rows:,} rows: one process {one:.1f} s, two ({when}) {two:.1f} s "
                f"({one / two:.2f}x); merged rows equal to one process's: {same}"
            )
        if not same:
            raise SystemExit("two processes' merged rows differ from one process's")

    growth = peaks[sizes[-1]] / peaks[sizes[0]]
    record.add_goals(
        [
            goal(
                f"peak memory, {sizes[-1]:,} rows over {sizes[0]:,}",
                growth,
                MEMORY_GROWTH,
                fmt=".2f",
                unit="x",
                op="<=",
            ),
        ]
    )
    print(f"peak memory {sizes[-1]:,} rows / {sizes[0]:,} rows: {growth:.2f}x")
    record.write(out_dir(args.out, args.quick))


def _rows(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if not line.startswith("#")]


if __name__ == "__main__":
    main()
