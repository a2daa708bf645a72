"""Forward-kinematics throughput of the default body: poses per second for batches of 1,
1,000 and 100,000, compile time apart from run time.

    python benchmarks/fk.py [--variant male50] [--repeats 7] [--x64]

Prints the machine and versions, then one row per (batch, output): the compile time, the
median run time over the repeats, and poses/s. "full" returns every sphere centre, feature,
centroid and the center of gravity; "joints" only the joint positions (XLA drops the rest).
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from common import bench, machine


def random_angles(body, n: int, rng: np.random.Generator) -> jnp.ndarray:
    k = body.n_segments
    a = np.stack(
        [
            rng.uniform(-np.pi, np.pi, (n, k)),
            rng.uniform(0, np.pi, (n, k)),
            rng.uniform(-1, 1, (n, k)),
        ],
        axis=-1,
    )
    return jnp.asarray(a, dtype=jnp.result_type(float))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="male50")
    parser.add_argument("--body", default=None, help="a body JSON file instead")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 1_000, 100_000])
    parser.add_argument("--x64", action="store_true", help="run in float64")
    args = parser.parse_args()
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import diffbody as db

    body = db.load_body(args.body, variant=args.variant)
    if not args.x64:
        body = jax.tree.map(
            lambda x: x.astype(jnp.float32) if isinstance(x, jax.Array) else x, body
        )
    print(machine())
    print(f"body: {body.name}, {body.n_segments} segments, {body.n_spheres} spheres")
    outputs = {
        "full": lambda p: db.forward(body, p),
        "joints": lambda p: db.forward(body, p).joint_positions,
    }
    rng = np.random.default_rng(0)
    print(f"{'batch':>8} {'output':>7} {'compile s':>10} {'run ms':>10} {'poses/s':>12}")
    for n in args.batches:
        angles = random_angles(body, n, rng).astype(body.lengths.dtype)
        pose = db.Pose(position=jnp.broadcast_to(body.rest_position, (n, 3)), angles=angles)
        for name, f in outputs.items():
            c, r = bench(jax.vmap(f), (pose,), args.repeats)
            print(f"{n:>8} {name:>7} {c:>10.2f} {r * 1e3:>10.3f} {n / r:>12,.0f}")


if __name__ == "__main__":
    main()
