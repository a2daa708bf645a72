"""The reach solver's choice: optimistix's least-squares solvers on the limbs' problem.

    python benchmarks/solvers.py [--quick] [--n N] [--max-steps 30] [--repeats N] [--x64]
                                 [--out DIR]

The problem is the first attempt of `diffbody.solve_reach` on one palm target
(`left_hand.palm`) with the default unknowns: the limbs' phase (the left clavicle, upper arm,
forearm and hand free within their limits, the rest held in the standard position), from
the first start (the closed-form limb start from the standard position), `--max-steps`
steps (30, solve_reach's default; 8 shows what one round of polishing reaches), tolerances
1 mm and 1 degree. It is built and solved by diffbody's own `solve_free`, with only the
solver swapped:

- diffbody: `reach_solver`, optimistix's Levenberg-Marquardt with the damped normal
  equations by Cholesky, which also stops as soon as every target row is within a
  hundredth of its tolerance (what solve_reach runs);
- the same with optimistix's default linear solve (QR);
- Levenberg-Marquardt: plain `optx.LevenbergMarquardt`, the same rtol and atol;
- Gauss-Newton, Dogleg: `optx.GaussNewton`, `optx.Dogleg`, the same rtol and atol.

Targets: those of the IK benchmark's left arm (benchmarks/ik.py, seed 0): the palm of
random left-arm poses within diffbody's limits (`peers.arm_poses`, `peers.palm_positions`),
1,000 of them (`--n`; `--quick`: 50), all solved at once under jax.vmap. "within 1 mm" is
the palm of the answer pose by `forward` (ik.py's `check`, not the solver's residual);
steps are optimistix's `num_steps` per target. Compile time and the median run time of
the whole batch after a warm-up (common.bench): under vmap a batch runs until its slowest
target stops, so an early stop shortens the run only when every target has stopped.
Float32 by default (what a user gets), float64 with `--x64`; on the CPU.
"""

import argparse
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import results
from common import TOL_POSITION, bench, limits_tol, load_body, machine, select_device, start_run

EFFECTOR = "left_hand.palm"
SEED = 0  # the IK benchmark's left-arm targets


def limbs_problem(body, xyz0):
    """The layout of solve_reach's first phase (the limbs) for one palm target, and the
    targets' arrays of that target (solve_reach's own resolution and phases)."""
    import diffbody as db
    from diffbody.ik._phases import phase_layouts
    from diffbody.problem._targets import resolve_targets

    ts, _ = resolve_targets(body, [db.Target.position(EFFECTOR, xyz0)])
    layouts = phase_layouts(body, [ts], spine=True, free_root=False, segments=None)
    return layouts[0], ts


def solvers(dtype) -> dict[str, optx.AbstractLeastSquaresSolver]:
    import lineax as lx

    from diffbody._solver import least_squares_solver
    from diffbody.ik._attempt import reach_solver

    reach = reach_solver(dtype)
    tol = {"rtol": reach.rtol, "atol": reach.atol}
    qr = lx.AutoLinearSolver(well_posed=None)
    return {
        "diffbody (LM, early stop)": reach,
        "LM, early stop, QR": least_squares_solver(reach.rtol, early_stop=True, linear_solver=qr),
        "Levenberg-Marquardt": optx.LevenbergMarquardt(**tol),
        "Gauss-Newton": optx.GaussNewton(**tol),
        "Dogleg": optx.Dogleg(**tol),
    }


def batch_solve(body, layout, ts, solver, max_steps: int):
    """fn(xyz (n, 3)) -> (poses, steps (n,)): the limbs' solve of each palm target from the
    closed-form limb start (the standard position elsewhere)."""
    import equinox as eqx

    from diffbody.ik._attempt import Settings, assess, solve_free
    from diffbody.problem._problem import make_problem

    dtype = body.lengths.dtype
    init = body.rest_pose()
    settings = Settings(jnp.asarray(1e-3, dtype), jnp.asarray(np.deg2rad(1.0), dtype), True)
    start, fresh = jnp.asarray(0), jnp.asarray(True)
    x0 = jnp.zeros(layout.n_free, dtype)

    def one(xyz):
        problem = make_problem(body, layout, init)
        targets = eqx.tree_at(lambda t: t.point_xyz, ts, xyz[None].astype(dtype))
        args = (problem, targets, x0, start, fresh, max_steps, settings)
        x, steps, _ = solve_free(*args, solver=solver)
        return assess(problem, init, targets, x, steps, settings).pose, steps

    return jax.vmap(one)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    results.add_arguments(parser)
    parser.add_argument("--n", type=int, default=None, help="palm targets (1,000; quick 50)")
    parser.add_argument("--max-steps", type=int, default=30, help="solver steps (30)")
    parser.add_argument("--repeats", type=int, default=None, help="timed runs (5; quick 2)")
    parser.add_argument("--x64", action="store_true", help="run in float64")
    args = parser.parse_args()
    select_device("cpu", args.x64)
    sys.stdout.reconfigure(line_buffering=True)
    n = args.n or (50 if args.quick else 1_000)
    repeats = args.repeats or (2 if args.quick else 5)
    import peers
    from ik import check

    body = load_body()
    dtype = body.lengths.dtype
    print(machine())
    targets = peers.palm_positions(body, peers.arm_poses(body, n, np.random.default_rng(SEED)))
    layout, ts = limbs_problem(body, targets[0])
    moving = sorted(
        {layout.chain.segments[k] for k in layout.swing_x + layout.swing_y + layout.twist}
    )
    names = ", ".join(body.segment_names[s] for s in moving)
    print(
        f"problem: {EFFECTOR}, the limbs' phase ({names}; {layout.n_free} unknowns), "
        f"from the closed-form limb start, {args.max_steps} steps"
    )
    print(f"targets: {n:,} palm positions of random in-limit left-arm poses (seed {SEED})")
    run = start_run("solvers", args, targets=n, seed=SEED, max_steps=args.max_steps)
    table = run.table(
        "choice",
        ["solver", "within 1 mm", "median steps", "90th pct steps", "compile (s)", "run (ms)"],
        "lrrrrr",
    )
    xyz = jnp.asarray(targets, dtype)
    print(
        f"\n  {'solver':<26} {'<=1mm':>7} {'median':>7} {'p90':>5} {'compile s':>10} "
        f"{'run ms':>9}  largest stop violation"
    )
    for name, solver in solvers(dtype).items():
        fn = batch_solve(body, layout, ts, solver, args.max_steps)
        compile_s, run_s = bench(fn, (xyz,), repeats)
        poses, steps = jax.jit(fn)(xyz)
        errors, violations = check(body, poses, targets)
        within = float(np.mean(errors <= TOL_POSITION))
        steps = np.asarray(steps)
        median, p90 = np.median(steps), np.percentile(steps, 90)
        print(
            f"  {name:<26} {within:>7.1%} {median:>7g} {p90:>5g} {compile_s:>10.2f} "
            f"{run_s * 1e3:>9.1f}  {violations.max():.1e} rad (tol {limits_tol():.0e})"
        )
        table.add(
            name,
            f"{within:.1%}",
            f"{median:g}",
            f"{p90:g}",
            f"{compile_s:.1f}",
            f"{run_s * 1e3:.0f}",
        )
    run.write(results.out_dir(args.out, args.quick))


if __name__ == "__main__":
    main()
