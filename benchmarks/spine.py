"""Bendspine throughput: calls per second for batches of 1, 1,000 and 100,000 (random
spine states and feasible targets), compile time apart from run time.

    python benchmarks/spine.py [--repeats 7] [--x64] [--quick] [--out DIR]
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np
import results
from common import bench, machine, ms, start_run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 1_000, 100_000])
    parser.add_argument("--x64", action="store_true", help="run in float64")
    results.add_arguments(parser)
    args = parser.parse_args()
    if args.quick:
        args.batches, args.repeats = [1, 1_000], 3
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import diffbody as db

    spine = db.load_spine()
    dtype = jnp.float64 if args.x64 else jnp.float32
    spine = jax.tree.map(lambda x: x.astype(dtype) if isinstance(x, jax.Array) else x, spine)
    print(machine())
    print(f"spine: {spine.n_joints} joints x 3 rotations; Bendspine with resistance")
    lo, hi = np.asarray(spine.lower), np.asarray(spine.upper)
    rng = np.random.default_rng(0)

    def call(current, target):
        return db.bendspine(spine, current, target, initiator=9, resistor=3, resistance=0.5)

    run = start_run("spine", args, batches=args.batches, repeats=args.repeats, seed=0)
    table = run.table(
        "throughput", ["batch", "compile (s)", "run (ms)", "calls/s", "reached"], "rrrrr"
    )
    print(f"{'batch':>8} {'compile s':>10} {'run ms':>10} {'calls/s':>12} {'reached':>8}")
    for n in args.batches:
        current = lo + (hi - lo) * rng.uniform(size=(n,) + lo.shape)
        target = lo.sum(0) + (hi - lo).sum(0) * rng.uniform(size=(n, 3))
        xs = (jnp.asarray(current, dtype), jnp.asarray(target, dtype))
        c, r = bench(jax.vmap(call), xs, args.repeats)
        reached = float(jnp.mean(jnp.all(jax.jit(jax.vmap(call))(*xs).reached, axis=-1)))
        print(f"{n:>8} {c:>10.2f} {r * 1e3:>10.3f} {n / r:>12,.0f} {reached:>8.1%}")
        table.add(f"{n:,}", f"{c:.1f}", ms(r), f"{n / r:,.0f}", f"{reached:.1%}")
    run.write(results.out_dir(args.out, args.quick))


if __name__ == "__main__":
    main()
