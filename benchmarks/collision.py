"""Contact throughput of the default body: self-distance queries against MuJoCo's collision,
and what the constraints (standing, balance, contact avoidance) cost a reach.

    python benchmarks/collision.py [--device cpu|gpu] [--quick] [--tables self_distance reach]
                                   [--batch 1024] [--mujoco-poses N] [--repeats 7]
                                   [--reach-rows 64] [--arm-rows 256]
                                   [--skip-mujoco] [--x64] [--variant male50] [--out DIR]

Prints the machine and versions, then each table of `--tables` (default: all of `TABLES`).

self_distance: one query is one pose's `diffbody.contact.closest_pair_gaps` over every
checked pair of segments (`sphere_pairs(body)`: every sphere pair of those segments, the
closest one less its rest overlap per segment pair), under jit(vmap) on a batch of `--batch`
poses, float32 unless `--x64`; compile time (`jax.jit(f).lower(...).compile()`) apart from
the median run time over the repeats after a warm-up. Two rows: "centres -> gaps" takes the
sphere centres (batch, n_sph, 3) as input; "pose -> gaps" takes pose angles and includes
`forward`, like for like with MuJoCo's row. The poses are random swings within each
segment's swing limits (uniform in the box, pulled into the cone) with every twist tau = 0,
so that the exported model's spheres sit where `forward` puts them.

MuJoCo: the body exported by `diffbody.export_mjcf` with the segment pairs diffbody never
checks excluded (the same pairs collide in both), qpos from `diffbody.mujoco_qpos` computed
beforehand; per pose `mj_kinematics` + `mj_collision` from a Python loop on one core
(MuJoCo's collision is single-threaded), on the same poses (the first `--mujoco-poses`),
median over the repeats; then the same loop split over one Python thread per core, each with
its own MjData (MuJoCo's calls release the GIL), and `mj_kinematics` alone for scale; all
before diffbody's rows, so that XLA's CPU threads do not compete with MuJoCo's. MuJoCo
returns every interpenetrating sphere pair (a contact each), diffbody every checked segment
pair's gap whether it touches or not: not the same output, the same question (what touches
what, how deep) of the same spheres. Goal: diffbody's "pose -> gaps" queries/s >= 10x the
one-core MuJoCo loop's (as benchmarks/fk.py compares kinematics); the ratio over the
threaded loop is printed beside it.

reach: see `reach`.

A table is a function (body, args, run) -> goals, named in `TABLES`; `--tables` picks some.
"""

import argparse
import os
import statistics
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
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
MUJOCO_FIGURE = (
    "self-distance queries (pose -> gaps, jit(vmap) batch) per s over MuJoCo "
    "mj_kinematics + mj_collision loop (1 core)"
)
CONTACTS = 4000  # MuJoCo's contact buffer (nconmax): a pose has a few hundred


def random_swing_angles(body, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, n_seg, 3) pose angles: every segment's swing vector uniform in its box of limits,
    pulled into its cone; every twist tau = 0."""
    import diffbody as db

    lo, hi = np.asarray(body.swing_lo, float), np.asarray(body.swing_hi, float)
    w = lo + (hi - lo) * rng.uniform(size=(n, *lo.shape))
    smax = np.asarray(body.swing_max, float)
    w *= np.minimum(1.0, smax / np.maximum(np.linalg.norm(w, axis=-1), 1e-300))[..., None]
    tau = np.zeros((n, body.n_segments))
    dtype = body.lengths.dtype
    to_angles = jax.jit(jax.vmap(lambda w, t: db.angles_from_swing(body, w, t)))
    return np.asarray(to_angles(jnp.asarray(w, dtype), jnp.asarray(tau, dtype)))


def mujoco_model(body):
    """The exported MJCF with diffbody's never-checked segment pairs excluded, compiled."""
    import mujoco

    import diffbody as db
    from diffbody.contact._pairs import excluded_segment_pairs

    names = body.segment_names
    exclude = [(names[a], names[b]) for a, b in excluded_segment_pairs(body)]
    with tempfile.TemporaryDirectory() as directory:
        path = db.export_mjcf(body, Path(directory) / "body.xml", exclude)
        spec = mujoco.MjSpec.from_file(str(path))
    spec.nconmax = CONTACTS
    return spec.compile()


def mujoco_loops(model, qpos: np.ndarray, repeats: int) -> dict[str, float]:
    """Median seconds of each MuJoCo loop over `qpos` (module docstring), and the mean
    number of contacts per pose."""
    import mujoco

    def loop(qs, collide: bool = True) -> float:
        data = mujoco.MjData(model)
        t0 = time.perf_counter()
        for q in qs:
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            if collide:
                mujoco.mj_collision(model, data)
        return time.perf_counter() - t0

    threads = os.cpu_count() or 1
    chunks = np.array_split(qpos, threads)

    def threaded() -> float:
        with ThreadPoolExecutor(threads) as pool:
            t0 = time.perf_counter()
            list(pool.map(loop, chunks))
            return time.perf_counter() - t0

    out = {}
    for name, run in [
        ("collision", lambda: loop(qpos)),
        ("threaded", threaded),
        ("kinematics", lambda: loop(qpos, collide=False)),
    ]:
        run()  # warm up
        out[name] = statistics.median(run() for _ in range(repeats))
    data, contacts = mujoco.MjData(model), 0
    for q in qpos:
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        if data.warning[mujoco.mjtWarning.mjWARN_CONTACTFULL].number:
            raise RuntimeError(f"MuJoCo's contact buffer ({CONTACTS}) overflowed")
        contacts += data.ncon
    out["contacts"] = contacts / len(qpos)
    out["threads"] = threads
    return out


def self_distance(body, args, run) -> list[Goal]:
    """The self_distance table (module docstring)."""
    import diffbody as db
    from diffbody.contact import closest_pair_gaps, sphere_pairs

    pairs = sphere_pairs(body)
    dtype = body.lengths.dtype
    i, j = jnp.asarray(pairs.i), jnp.asarray(pairs.j)
    allowance = jnp.asarray(pairs.allowance, dtype)
    group, n_groups = pairs.segment_pair, len(pairs.segments)
    print(
        f"\nself_distance: {n_groups} checked segment pairs, {len(pairs):,} sphere pairs per "
        f"query; batch {args.batch:,}, {jnp.dtype(dtype).name}"
    )

    def from_centres(centres):
        return closest_pair_gaps(centres, body.sphere_radii, i, j, allowance, group, n_groups)[0]

    def from_pose(angles):
        fk = db.forward(body, db.Pose(body.rest_position, angles))
        return from_centres(fk.sphere_centers)

    angles = random_swing_angles(body, args.batch, np.random.default_rng(0))
    angles_j = jnp.asarray(angles, dtype)
    centres = jax.jit(
        jax.vmap(lambda a: db.forward(body, db.Pose(body.rest_position, a)).sphere_centers)
    )(angles_j)
    table = run.table(
        "self_distance", ["", "poses", "compile (s)", "run (ms)", "queries/s"], "lrrrr"
    )
    print(f"{'':>44} {'poses':>7} {'compile s':>10} {'run ms':>10} {'queries/s':>12}")

    def row(name, n, compile_s, run_s):
        c = "-" if compile_s is None else f"{compile_s:.2f}"
        print(f"{name:>44} {n:>7,} {c:>10} {run_s * 1e3:>10.2f} {n / run_s:>12,.0f}")
        table.add(
            name,
            f"{n:,}",
            "-" if compile_s is None else f"{compile_s:.1f}",
            ms(run_s),
            f"{n / run_s:,.0f}",
        )

    # MuJoCo first, before XLA's CPU threads are busy with diffbody's batches.
    m = None if args.skip_mujoco else mujoco_figures(body, angles_j[: args.mujoco_poses], args)
    c_s, r_s = bench(jax.vmap(from_centres), (centres,), args.repeats)
    row("diffbody jit(vmap): centres -> gaps", args.batch, c_s, r_s)
    c_p, r_p = bench(jax.vmap(from_pose), (angles_j,), args.repeats)
    row("diffbody jit(vmap): pose -> gaps (forward incl.)", args.batch, c_p, r_p)
    diffbody_qps = args.batch / r_p
    if m is None:
        return [not_measured(MUJOCO_FIGURE, f">= {GOAL_MUJOCO_RATIO:g}x", "--skip-mujoco")]
    n = args.mujoco_poses
    row(f"MuJoCo {m['version']} kinematics + collision, 1 core", n, None, m["collision"])
    row(f"MuJoCo, the same on {m['threads']} threads", n, None, m["threaded"])
    row("MuJoCo mj_kinematics alone, 1 core", n, None, m["kinematics"])
    mujoco_qps, threaded_qps = n / m["collision"], n / m["threaded"]
    print(
        f"  MuJoCo contacts per pose: {m['contacts']:.0f} (rest overlaps included); ratio "
        f"{diffbody_qps / mujoco_qps:.1f}x over MuJoCo on 1 core, "
        f"{diffbody_qps / threaded_qps:.1f}x over MuJoCo on {m['threads']} threads"
    )
    return [
        goal(
            f"{MUJOCO_FIGURE} (batch {args.batch:,}: {diffbody_qps:,.0f} against "
            f"{mujoco_qps:,.0f}; {threaded_qps:,.0f} on {m['threads']} threads)",
            diffbody_qps / mujoco_qps,
            GOAL_MUJOCO_RATIO,
            fmt=".1f",
            unit="x",
        )
    ]


def mujoco_figures(body, angles, args) -> dict:
    """`mujoco_loops` on the exported model over the poses of `angles` (n, n_seg, 3)."""
    import mujoco

    import diffbody as db

    model = mujoco_model(body)
    n = angles.shape[0]
    qpos = np.asarray(
        db.mujoco_qpos(body, db.Pose(jnp.broadcast_to(body.rest_position, (n, 3)), angles)),
        np.float64,
    )
    if qpos.shape[1] != model.nq:
        raise ValueError(f"mujoco_qpos gives {qpos.shape[1]} entries, the model has {model.nq}")
    return mujoco_loops(model, qpos, args.repeats) | {"version": mujoco.__version__}


# name -> a function (body, args, run) -> list of goals; each fills run.table(name, ...).
# The reaches of the `reach` table.
GOAL_ON_OVER_OFF = 2.0  # with avoidance and balance, at most this many times the time
GOAL_ARM_ONLY = 1.05  # arm-only reaches with standing on: no slower than off, within 5 %
ARM_SPHERES = ("left_upper_arm", "left_forearm", "left_hand")


def _rate(fn, n: int, repeats: int) -> tuple[float, float, object]:
    """(first call s, median of later calls s, the last result) of fn() over n rows."""
    out, first = None, 0.0
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return first, statistics.median(times), out


def reach(body, args, run) -> list[Goal]:
    """The reach table: what the constraints cost a reach.

    Far reaches: `--reach-rows` left-palm targets 0.75-1.2 m in front of the left shoulder,
    0.3 m either side, 0.4 m up or down (seed 1), by `solve_reach_batch` with the default
    unknowns: "off" with standing=False (the pelvis fixed in space, the spine alone bends;
    no constraint), "on" with standing (feet planted, balance, the floor: the default) and
    `Target.no_contact` of the left arm's segments (the body). Goal: on costs less than
    2x off in solves/s. Not the same answers: off bends the spine as far as it goes, on
    stands and keeps clear; the success rates are printed beside.

    Arm-only reaches: palms of random left-arm poses (`peers.arm_poses`, seed 0), reached
    by the arm alone, so standing never joins: warm `solve_reach` (median of `--repeats`
    calls on distinct targets, interleaved) and `solve_reach_batch`, standing on (the
    default) against off. Goal: on no slower than off, within 5 %."""
    from peers import arm_poses, palm_positions

    import diffbody as db

    n = args.reach_rows
    rest = db.forward(body, body.rest_pose())
    shoulder = np.asarray(rest.joint_positions[body.joint_index("left_shoulder")])
    rng = np.random.default_rng(1)
    far = shoulder + np.stack(
        [rng.uniform(0.75, 1.2, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.4, 0.4, n)], -1
    )
    avoid = [db.Target.no_contact(ARM_SPHERES)]
    table = run.table(
        "reach", ["", "rows", "first call (s)", "run (s)", "reached", "solves/s"], "lrrrrr"
    )
    print(f"\nreach: {n} far left-palm targets (0.75-1.2 m in front of the shoulder)")
    print(f"{'':>52} {'rows':>5} {'first s':>8} {'run s':>8} {'reached':>8} {'solves/s':>9}")

    def row(name, rows, first, run_s, out):
        ok = float(np.mean(np.asarray(out.status) == db.ReachStatus.SUCCESS))
        print(f"{name:>52} {rows:>5} {first:>8.1f} {run_s:>8.2f} {ok:>8.1%} {rows / run_s:>9.1f}")
        table.add(
            name, f"{rows:,}", f"{first:.1f}", f"{run_s:.2f}", f"{ok:.1%}", f"{rows / run_s:,.1f}"
        )
        return ok

    def batch(xyz, **kw):
        return lambda: db.solve_reach_batch(body, "left_hand.palm", xyz, progress=False, **kw)

    repeats = max(1, args.repeats // 3)
    f_off, r_off, o_off = _rate(batch(far, standing=False), n, repeats)
    row("off: pelvis fixed, spine bends (standing=False)", n, f_off, r_off, o_off)
    f_on, r_on, o_on = _rate(batch(far, constraints=avoid), n, repeats)
    ok_on = row("on: standing, balance, floor, arm avoids the body", n, f_on, r_on, o_on)
    violated = int(np.sum(np.asarray(o_on.status) == db.ReachStatus.CONSTRAINT_VIOLATED))
    constrained = int(np.sum(np.asarray(o_on.status) == db.ReachStatus.CONSTRAINED))
    print(f"  on: {constrained} constrained (kept the constraints, missed), {violated} violated")

    poses = arm_poses(body, args.arm_rows, np.random.default_rng(0))
    palms = palm_positions(body, poses)
    f_a0, r_a0, o_a0 = _rate(batch(palms, standing=False), len(palms), repeats)
    row("arm-only batch, standing off", len(palms), f_a0, r_a0, o_a0)
    f_a1, r_a1, o_a1 = _rate(batch(palms), len(palms), repeats)
    row("arm-only batch, standing on (default)", len(palms), f_a1, r_a1, o_a1)
    # Warm single solves, interleaved: on and off alternate over the same targets.
    single = {False: [], True: []}
    for standing in (False, True):  # warm both
        db.solve_reach(body, [db.Target.position("left_hand.palm", palms[0])], standing=standing)
    for xyz in palms[: args.repeats * 3]:
        for standing in (False, True):
            t0 = time.perf_counter()
            out = db.solve_reach(
                body, [db.Target.position("left_hand.palm", xyz)], standing=standing
            )
            jax.block_until_ready(out.pose.angles)
            single[standing].append(time.perf_counter() - t0)
    s_off, s_on = (statistics.median(single[k]) for k in (False, True))
    print(f"  arm-only solve_reach warm median: off {s_off * 1e3:.2f} ms, on {s_on * 1e3:.2f} ms")
    table.add(
        "arm-only solve_reach warm, standing off", "1", "-", ms(s_off), "-", f"{1 / s_off:,.0f}"
    )
    table.add("arm-only solve_reach warm, standing on", "1", "-", ms(s_on), "-", f"{1 / s_on:,.0f}")
    return [
        goal(
            f"far reaches: avoidance and balance on over off, time ({n} rows; "
            f"{ok_on:.0%} reached on)",
            r_on / r_off,
            GOAL_ON_OVER_OFF,
            fmt=".2f",
            unit="x",
            op="<",
        ),
        goal(
            f"arm-only solve_reach_batch ({len(palms)} rows): standing on over off, time",
            r_a1 / r_a0,
            GOAL_ARM_ONLY,
            fmt=".2f",
            unit="x",
            op="<=",
        ),
        goal(
            "arm-only solve_reach warm: standing on over off, time",
            s_on / s_off,
            GOAL_ARM_ONLY,
            fmt=".2f",
            unit="x",
            op="<=",
        ),
    ]


TABLES = {"self_distance": self_distance, "reach": reach}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--device", choices=("cpu", "gpu"), default="cpu", help="gpu: JAX's default backend"
    )
    results.add_arguments(parser)
    parser.add_argument("--tables", nargs="+", choices=tuple(TABLES), default=tuple(TABLES))
    parser.add_argument("--variant", default="male50")
    parser.add_argument("--batch", type=int, default=None, help="default 1,024 (--quick 64)")
    parser.add_argument(
        "--mujoco-poses", type=int, default=None, help="the first N of the batch (default all)"
    )
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--reach-rows", type=int, default=None, help="default 64 (--quick 4)")
    parser.add_argument("--arm-rows", type=int, default=None, help="default 256 (--quick 8)")
    parser.add_argument("--skip-mujoco", action="store_true", help="no MuJoCo comparison")
    parser.add_argument("--x64", action="store_true", help="run in float64")
    args = parser.parse_args()
    select_device(args.device, args.x64)
    args.batch = args.batch or (64 if args.quick else 1024)
    args.mujoco_poses = min(args.mujoco_poses or args.batch, args.batch)
    args.reach_rows = args.reach_rows or (4 if args.quick else 64)
    args.arm_rows = args.arm_rows or (8 if args.quick else 256)
    if args.quick:
        args.repeats = 3
    body = load_body(variant=args.variant)
    print(machine())
    print(f"body: {body.name}, {body.n_segments} segments, {body.n_spheres} spheres")
    run = start_run(
        "collision",
        args,
        body=body.name,
        tables=list(args.tables),
        batch=args.batch,
        mujoco_poses=args.mujoco_poses,
        repeats=args.repeats,
        reach_rows=args.reach_rows,
        arm_rows=args.arm_rows,
        seed=0,
    )
    goals = []
    for name in args.tables:
        goals += TABLES[name](body, args, run)
    print_goals(goals, f"goals (diffbody on {args.device})")
    run.add_goals(goals)
    run.write(results.out_dir(args.out, args.quick))


if __name__ == "__main__":
    main()
