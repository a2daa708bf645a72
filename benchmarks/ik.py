"""Inverse-kinematics speed, success and compile time, against IKPy and pytorch_kinematics.

Each figure is printed beside the project's goal for it (met / not met).

    python benchmarks/ik.py [--n 1000] [--n-ikpy 200] [--n-body 256] [--repeats 20]
                            [--chunk-size 4096] [--x64] [--skip-peers]

Targets: the palm (`left_hand.palm`) of random left-arm poses within diffbody's anatomical
limits (`peers.arm_poses`, `peers.palm_positions`, fixed rng seeds), so every target is
reachable; every solver gets the same targets. An error is the distance from the target of
the palm at the answer (diffbody: its reported residual; peers: their own forward
kinematics), success is an error of at most 1 mm.

(a) Left arm, shoulder to palm: the unknowns of the upper arm, forearm and hand, trunk and
clavicle at rest (the peers' problem, see benchmarks/peers.py). diffbody solves `--n`
targets with `solve_reach_batch(..., segments=arm)` in two settings, the default (up to 8
starts of 30 steps: every target from the initial posture, then the misses from the other
starts) and 1 start only. Compile time: the first call on one chunk compiles and solves it; the
full run after it reuses the compiled function, so compile = first call - one chunk's share
of the run. The peers' setup is building their chain plus one warm-up solve; IKPy (one
SciPy least-squares per target, tens of solves/s) gets only the first `--n-ikpy` targets.
The last column is diffbody's default solves/s over the row's.

(b) Whole body with the spine: palm targets made the same way (other seeds), with
`solve_reach`'s default unknowns (every segment from the root to the palm, the spine as its
Bendspine target, root fixed). A single `solve_reach` call: its first call (compile + one
solve) for 1 and up to 8 starts, then the median over `--repeats` further calls on other targets
(same shapes: no recompile) of the wall time a user sees, Python-side work included. Then
`solve_reach_batch` on `--n-body` targets, timed as in (a).

Float32 by default (what a user gets; the body is cast to it), float64 with `--x64`.
"""

import argparse
import importlib.metadata
import statistics
import tempfile
import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from common import machine

ARM_SEGMENTS = ("left_upper_arm", "left_forearm", "left_hand")
TOL = 1e-3  # m: what counts as reached
GOAL_SOLVES_PER_S = 100_000
GOAL_SUCCESS = 0.995
GOAL_PEER_RATIO = 10.0
GOAL_SINGLE_S = 2e-3
GOAL_COMPILE_S = 5.0


@dataclass(frozen=True)
class Row:
    """One solver's run over a batch of targets."""

    solver: str
    settings: str
    setup_s: float  # diffbody: compile; peers: chain + one warm-up solve
    run_s: float
    errors: np.ndarray  # (n,) m

    @property
    def success(self) -> float:
        return float(np.mean(self.errors <= TOL))

    @property
    def solves_per_s(self) -> float:
        return len(self.errors) / self.run_s


def timed(fn, *args, **kwargs):
    """(fn's result, once ready; wall seconds)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - t0


def batch_row(db, body, targets: np.ndarray, chunk_size: int, settings: str, **kwargs) -> Row:
    """`solve_reach_batch` on the palm targets (n, 3): compile time apart from run time."""
    chunk = min(chunk_size, len(targets))

    def solve(points):
        return db.solve_reach_batch(
            body, ["left_hand.palm"], points, chunk_size=chunk, progress=False, **kwargs
        )

    _, first_s = timed(solve, targets[:chunk])
    out, run_s = timed(solve, targets)
    n_chunks = -(-len(targets) // chunk)
    return Row("diffbody", settings, first_s - run_s / n_chunks, run_s, out.residuals[:, 0])


def print_rows(rows: list[Row], reference: Row | None = None) -> None:
    """A table of rows; the last column is reference's solves/s over the row's."""
    widths = (18, 26, 7, 8, 8, 7, 9, 10, 10)
    header = ("solver", "settings", "targets", "setup s", "run s", "<=1mm", "median mm")
    header += ("solves/s", "diffbody x")
    print(" ".join(f"{h:>{w}}" for h, w in zip(header, widths)))
    for r in rows:
        cells = (r.solver, r.settings, len(r.errors), f"{r.setup_s:.2f}", f"{r.run_s:.3f}")
        cells += (f"{r.success:.1%}", f"{np.median(r.errors) * 1e3:.2e}")
        ratio = f"{reference.solves_per_s / r.solves_per_s:.1f}" if reference else "-"
        cells += (f"{r.solves_per_s:,.0f}", ratio)
        print(" ".join(f"{c:>{w}}" for c, w in zip(cells, widths)))


def goal(name: str, measured: str, met: bool) -> None:
    print(f"  {name:<52} {measured:<28} {'met' if met else 'not met'}")


def versions(packages: list[str]) -> str:
    return ", ".join(f"{p} {importlib.metadata.version(p)}" for p in packages)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="arm targets")
    parser.add_argument("--n-ikpy", type=int, default=200, help="of those, for IKPy")
    parser.add_argument("--n-body", type=int, default=256, help="whole-body batch targets")
    parser.add_argument("--repeats", type=int, default=20, help="warm single solves")
    parser.add_argument("--chunk-size", type=int, default=4096, help="solve_reach_batch's")
    parser.add_argument("--x64", action="store_true", help="run in float64")
    parser.add_argument("--skip-peers", action="store_true", help="diffbody only")
    args = parser.parse_args()
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import peers

    import diffbody as db

    body = db.load_body()
    if not args.x64:
        body = jax.tree.map(
            lambda x: x.astype(jnp.float32) if isinstance(x, jax.Array) else x, body
        )
    print(machine())
    print(f"versions: {versions(['diffbody', 'optimistix', 'equinox'])}")
    if not args.skip_peers:
        print(f"peers: {versions(['ikpy', 'pytorch-kinematics', 'torch', 'scipy'])}")

    def palm_targets(n: int, seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        return peers.palm_positions(body, peers.arm_poses(body, n, rng))

    # (a) left arm
    targets = palm_targets(args.n, seed=0)
    print(f"\n(a) left arm, shoulder to palm: {args.n} random reachable palm targets")
    rows = [
        batch_row(
            db,
            body,
            targets,
            args.chunk_size,
            f"starts={starts}, max_steps=30",
            segments=ARM_SEGMENTS,
            starts=starts,
        )
        for starts in (8, 1)
    ]
    default = rows[0]
    peer_rows = []
    if not args.skip_peers:
        with tempfile.TemporaryDirectory() as directory:
            chain = peers.arm_chain(body, directory)
            seed_q = peers.rest_joint_values(body, chain)
            results = [
                peers.solve_ikpy(chain, targets[: args.n_ikpy], seed_q),
                peers.solve_pytorch_kinematics(chain, targets, seed_q),
            ]
        short = {"ikpy": "defaults", "pytorch_kinematics": f"{peers.PK_RETRIES} starts"}
        peer_rows = [Row(r.name, short[r.name], r.setup_s, r.run_s, r.errors) for r in results]
        rows += peer_rows
    print_rows(rows, reference=default)
    dtype = "float64" if args.x64 else "float32"
    print(f"  diffbody: solve_reach_batch, segments={ARM_SEGMENTS}, {dtype}")
    print("  diffbody x: diffbody's default solves/s over the row's")
    if not args.skip_peers:
        print(f"  ikpy: the first {args.n_ikpy} targets only (one SciPy solve per target)")
        for r in results:
            print(f"  {r.name} {r.version}: {r.settings}")

    # (b) whole body with the spine
    single = palm_targets(1 + args.repeats, seed=1)
    print("\n(b) whole body with the spine: palm targets, default unknowns (root to palm, the")
    print("    spine as its Bendspine target), root fixed")
    print(f"{'solve_reach':>18} {'first call s':>13} {'warm median ms':>15} {'<=1mm':>7}")
    first_s, warm_s = {}, {}
    for starts in (1, 8):

        def solve(xyz, starts=starts):
            return db.solve_reach(body, [db.Target.position("left_hand.palm", xyz)], starts=starts)

        _, first_s[starts] = timed(solve, single[0])
        runs = [timed(solve, xyz) for xyz in single[1:]]
        warm_s[starts] = statistics.median(t for _, t in runs)
        reached = np.mean([float(out.residuals[0]) <= TOL for out, _ in runs])
        print(
            f"{f'starts={starts}':>18} {first_s[starts]:>13.2f} {warm_s[starts] * 1e3:>15.2f} "
            f"{reached:>7.1%}"
        )
    print("  (starts is traced: the second setting reuses the first's compiled solve)")
    body_row = batch_row(
        db, body, palm_targets(args.n_body, seed=2), args.chunk_size, "default, starts=8"
    )
    print_rows([body_row])

    print("\ngoals (diffbody's default settings)")
    goal(
        f"arm >= {GOAL_SOLVES_PER_S:,} solves/s at >= {GOAL_SUCCESS:.1%}",
        f"{default.solves_per_s:,.0f}/s at {default.success:.1%}",
        default.solves_per_s >= GOAL_SOLVES_PER_S and default.success >= GOAL_SUCCESS,
    )
    if peer_rows:
        fastest = max(peer_rows, key=lambda r: r.solves_per_s)
        ratio = default.solves_per_s / fastest.solves_per_s
        goal(
            f">= {GOAL_PEER_RATIO:g}x the fastest peer",
            f"{ratio:.1f}x {fastest.solver}",
            ratio >= GOAL_PEER_RATIO,
        )
    else:
        print(f"  >= {GOAL_PEER_RATIO:g}x the fastest peer: not measured (--skip-peers)")
    goal(
        f"whole-body single solve < {GOAL_SINGLE_S * 1e3:g} ms warm",
        f"{warm_s[8] * 1e3:.2f} ms",
        warm_s[8] < GOAL_SINGLE_S,
    )
    for name, seconds in (
        ("arm batch", default.setup_s),
        # starts is traced: the first setting timed compiles for both.
        ("whole-body single, first call", max(first_s.values())),
    ):
        goal(
            f"first compile < {GOAL_COMPILE_S:g} s: {name}",
            f"{seconds:.2f} s",
            seconds < GOAL_COMPILE_S,
        )


if __name__ == "__main__":
    main()
