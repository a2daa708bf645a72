"""Forward-kinematics throughput of the default body, and against MuJoCo's C kinematics.

    python benchmarks/fk.py [--device cpu|gpu] [--quick] [--skip-mujoco] [--variant male50]
                            [--repeats 7] [--batches 1 1000 100000] [--comparison-batch N]
                            [--mujoco-poses N] [--x64] [--matmul-precision default|highest]

Prints the machine and versions, then one row per (batch, output): the compile time
(`jax.jit(f).lower(...).compile()`), the median run time over the repeats after a warm-up,
and poses/s. "full" returns every sphere centre, feature, centroid and the center of
gravity; "joints" only the joint positions (XLA drops the rest). Poses are random angles
(theta, phi, tau) over their full ranges, limits not applied (forward does not read them).

Then the comparison with MuJoCo (`mujoco_comparison`): the body exported by
`diffbody.export_mjcf`, `mujoco.mj_kinematics` (frames of all bodies, geoms and sites: the
spheres and features) called one pose at a time from a Python loop, on one core (MuJoCo's
kinematics is single-threaded), qpos from `diffbody.mujoco_qpos` computed beforehand; against
the full `forward` under jit(vmap) on a batch of 100,000 (`--comparison-batch`). Both on the
same random poses; MuJoCo's body positions are checked against diffbody's proximal joints.
Goal: diffbody's poses/s >= 10x MuJoCo's.

`--device gpu` runs diffbody on JAX's default backend (a GPU) with batches up to 1,000,000;
MuJoCo stays on the CPU.
"""

import argparse
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import results
from common import (
    Goal,
    bench,
    goal,
    load_body,
    machine,
    ms,
    not_measured,
    print_goals,
    select_device,
    start_run,
)

GOAL_MUJOCO_RATIO = 10.0
MUJOCO_FIGURE = "forward full body, jit(vmap) batch, poses/s over MuJoCo mj_kinematics loop"


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
    return jnp.asarray(a, dtype=body.lengths.dtype)


def random_poses(body, n: int, rng: np.random.Generator):
    import diffbody as db

    angles = random_angles(body, n, rng)
    return db.Pose(position=jnp.broadcast_to(body.rest_position, (n, 3)), angles=angles)


@dataclass(frozen=True)
class MujocoComparison:
    """diffbody's batched forward against MuJoCo's mj_kinematics one pose at a time."""

    batch: int  # diffbody's batch
    compile_s: float
    run_s: float  # diffbody, median over the repeats
    n_mujoco: int  # poses in MuJoCo's loop
    mujoco_s: float  # MuJoCo's loop, median over the repeats
    max_error: float  # m: MuJoCo's body positions against diffbody's proximal joints
    mujoco_version: str

    @property
    def poses_per_s(self) -> float:
        return self.batch / self.run_s

    @property
    def mujoco_poses_per_s(self) -> float:
        return self.n_mujoco / self.mujoco_s

    @property
    def ratio(self) -> float:
        return self.poses_per_s / self.mujoco_poses_per_s

    def goal(self) -> Goal:
        return goal(
            f"{MUJOCO_FIGURE} (batch {self.batch:,}: {self.poses_per_s:,.0f} against "
            f"{self.mujoco_poses_per_s:,.0f})",
            self.ratio,
            GOAL_MUJOCO_RATIO,
            fmt=".1f",
            unit="x",
        )


def mujoco_comparison(
    body, batch: int = 100_000, n_mujoco: int = 10_000, repeats: int = 5, seed: int = 1
) -> MujocoComparison:
    """Full-body `forward` under jit(vmap) on `batch` random poses against MuJoCo's
    `mj_kinematics` on the exported MJCF, one pose at a time from a Python loop (the first
    `n_mujoco` of the same poses); medians over `repeats` (module docstring)."""
    import mujoco

    import diffbody as db

    poses = random_poses(body, batch, np.random.default_rng(seed))
    compile_s, run_s = bench(jax.vmap(lambda p: db.forward(body, p)), (poses,), repeats)

    head = jax.tree.map(lambda x: x[:n_mujoco], poses)
    qpos = np.asarray(db.mujoco_qpos(body, head), np.float64)
    with tempfile.TemporaryDirectory() as directory:
        path = db.export_mjcf(body, Path(directory) / "body.xml")
        model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    if qpos.shape[1] != model.nq:
        raise ValueError(f"mujoco_qpos gives {qpos.shape[1]} entries, the model has nq={model.nq}")

    def loop() -> float:
        t0 = time.perf_counter()
        for q in qpos:
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
        return time.perf_counter() - t0

    loop()  # warm up
    mujoco_s = statistics.median(loop() for _ in range(repeats))

    # The same kinematics: body positions (each segment's proximal joint) on a few poses.
    ids = np.array([model.body(name).id for name in body.segment_names])
    proximal = np.asarray(body.proximal_joint)
    fk = jax.jit(jax.vmap(lambda p: db.forward(body, p).joint_positions))
    check = min(n_mujoco, 20)
    joints = np.asarray(fk(jax.tree.map(lambda x: x[:check], head)))
    max_error = 0.0
    for q, p in zip(qpos[:check], joints):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        max_error = max(max_error, float(np.max(np.abs(data.xpos[ids] - p[proximal]))))
    return MujocoComparison(
        batch, compile_s, run_s, len(qpos), mujoco_s, max_error, mujoco.__version__
    )


def print_comparison(c: MujocoComparison) -> None:
    print(f"\nforward (full) against MuJoCo {c.mujoco_version} mj_kinematics on the exported MJCF")
    print(f"{'':>28} {'poses':>9} {'compile s':>10} {'run ms':>10} {'poses/s':>12}")
    print(
        f"{'diffbody jit(vmap(forward))':>28} {c.batch:>9,} {c.compile_s:>10.2f} "
        f"{c.run_s * 1e3:>10.2f} {c.poses_per_s:>12,.0f}"
    )
    print(
        f"{'MuJoCo, Python loop, 1 core':>28} {c.n_mujoco:>9,} {'-':>10} "
        f"{c.mujoco_s * 1e3:>10.2f} {c.mujoco_poses_per_s:>12,.0f}"
    )
    print(f"  ratio {c.ratio:.1f}x; MuJoCo body positions vs diffbody joints: {c.max_error:.1e} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--device", choices=("cpu", "gpu"), default="cpu", help="gpu: JAX's default backend"
    )
    results.add_arguments(parser)
    parser.add_argument("--variant", default="male50")
    parser.add_argument("--body", default=None, help="a body JSON file instead")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batches", type=int, nargs="+", default=None)
    parser.add_argument("--comparison-batch", type=int, default=None, help="default 100,000")
    parser.add_argument("--mujoco-poses", type=int, default=None, help="default 10,000")
    parser.add_argument("--skip-mujoco", action="store_true", help="no MuJoCo comparison")
    parser.add_argument("--x64", action="store_true", help="run in float64")
    parser.add_argument(
        "--matmul-precision",
        choices=("default", "highest"),
        default="default",
        help="JAX's matmul precision (default: JAX's; on a GPU float32 products round to TF32)",
    )
    args = parser.parse_args()
    select_device(args.device, args.x64, args.matmul_precision)
    if args.batches is None:
        args.batches = [1, 1_000] if args.quick else [1, 1_000, 100_000]
        if args.device == "gpu" and not args.quick:
            args.batches.append(1_000_000)
    comparison_batch = args.comparison_batch or (1_000 if args.quick else 100_000)
    mujoco_poses = args.mujoco_poses or (200 if args.quick else 10_000)
    repeats = 3 if args.quick else args.repeats
    import diffbody as db

    body = load_body(path=args.body, variant=args.variant)
    print(machine())
    print(f"body: {body.name}, {body.n_segments} segments, {body.n_spheres} spheres")
    run = start_run(
        "fk",
        args,
        body=body.name,
        batches=args.batches,
        repeats=repeats,
        comparison_batch=comparison_batch,
        mujoco_poses=mujoco_poses,
    )
    table = run.table(
        "throughput", ["batch", "output", "compile (s)", "run (ms)", "poses/s"], "rlrrr"
    )
    outputs = {
        "full": lambda p: db.forward(body, p),
        "joints": lambda p: db.forward(body, p).joint_positions,
    }
    rng = np.random.default_rng(0)
    print(f"{'batch':>9} {'output':>7} {'compile s':>10} {'run ms':>10} {'poses/s':>12}")
    for n in args.batches:
        pose = random_poses(body, n, rng)
        for name, f in outputs.items():
            c, r = bench(jax.vmap(f), (pose,), repeats)
            print(f"{n:>9,} {name:>7} {c:>10.2f} {r * 1e3:>10.3f} {n / r:>12,.0f}")
            table.add(f"{n:,}", name, f"{c:.1f}", ms(r), f"{n / r:,.0f}")

    if args.skip_mujoco:
        row = not_measured(MUJOCO_FIGURE, f">= {GOAL_MUJOCO_RATIO:g}x", "--skip-mujoco")
    else:
        comparison = mujoco_comparison(body, comparison_batch, mujoco_poses, repeats)
        print_comparison(comparison)
        row = comparison.goal()
    print_goals([row], f"goals (diffbody on {args.device})")
    run.add_goals([row])
    run.write(results.out_dir(args.out, args.quick))


if __name__ == "__main__":
    main()
