"""Inverse kinematics: every figure beside its goal (met / not met), with the machine and versions.

    python benchmarks/ik.py [--device cpu|gpu] [--quick] [--skip-peers] [--skip-cli]
                            [--skip-fk] [--n N] [--n-ikpy N] [--n-body N] [--repeats N]
                            [--chunk-size N] [--x64] [--matmul-precision default|highest]
                            [--out DIR]

Targets: the palm (`left_hand.palm`) of random left-arm poses within diffbody's anatomical
limits (`peers.arm_poses`, `peers.palm_positions`, fixed seeds): the upper arm, forearm and
hand move, everything else stays at rest, so every target is reachable by the arm alone.
A target counts as solved ("success") when the palm of the answer, by `forward` at full
float32 precision (not the solver's own residual), is within 1 mm of it and the answer is
within the joint limits (`diffbody.stop_violation` <= 256 eps of the dtype, 3e-5 rad in
float32: `within_limits`' default, above float32 rounding; a pose carrying a spine target
is checked with its vertebrae bent to it, as `forward` bends them). A speed figure counts
only at >= 99.9 % success, and its success rate is printed beside it.

The figures (goals for a 2-core CPU, float32, the default body `diffbody.load_body()`):

1. CLI: the README command as written, `diffbody reach --effector left_hand.palm --target
   0.35 0.3 1.1 --out reach.pose.json --png reach.png`, end-to-end wall time of the subprocess
   with an empty compilation cache (a fresh `JAX_COMPILATION_CACHE_DIR`), < 3 s; then again
   with the cache it filled, < 1 s. (`--skip-cli`)
2. `solve_reach` on the whole body (default unknowns: root to palm, the spine as its
   Bendspine target, root fixed), one palm target, in a fresh process with JAX's persistent
   compilation cache off (`common.fresh_process`): the first call (trace, compile, solve)
   < 3 s; its compile from cold, the first call minus a second identical one, < 5 s.
3. The same, warm (in this process): median wall time over `--repeats` calls on other
   targets (same shapes, Python-side work included), < 1 ms.
4. `solve_reach_batch` on the left arm (segments upper arm, forearm, hand), `--n` targets:
   compile from cold (a fresh process as in 2, first call - second), < 5 s; success
   >= 99.9 %; solves/s (the second call in this process) over pytorch_kinematics' on the
   same targets in the same run, >= 10x (`--skip-peers`; IKPy is run on the first
   `--n-ikpy` targets for reference).
5. `solve_reach_batch` on the whole body (default unknowns), `--n-body` targets: compile
   from cold as in 4, < 5 s; solves/s of the second call in this process, >= 5,000.
6. Posture on arm-reachable targets (those of 3 and 5): the largest change of the spine
   target from the initial posture's spine (`spine_angles(body, body.spine,
   body.rest_pose()).sum(0)`) per component, and the largest swing change (`swing_vector`)
   of any segment other than the left arm and left clavicle, <= 2 degrees each: a target
   the arm can reach should move the arm only.
7. `forward` on the full body (spheres, features, center of gravity) under jit(vmap) on
   100,000 poses, poses/s over MuJoCo's `mj_kinematics` on the exported MJCF, one pose at a
   time from a Python loop (`fk.mujoco_comparison`), >= 10x. (`--skip-fk`)

`--device gpu` runs diffbody on JAX's default backend (a GPU) with an arm batch of 100,000
and a whole-body batch of 4,096, each in one chunk, and pytorch_kinematics on torch's CUDA
device; its goals: arm >= 2,000,000 solves/s and >= 10x pytorch_kinematics on the same GPU,
whole body >= 200,000 solves/s (the other goals as on the CPU). `--quick` takes small
batches and few repeats, and runs no peer, command line, fresh process or MuJoCo: a smoke
run whose figures are not the goals' sizes. On a GPU, JAX's default
matmul precision rounds float32 products to TF32 (about 3 decimal digits), in the solver as
everywhere; `--matmul-precision highest` runs everything at full float32 precision.

Peer settings: benchmarks/peers.py (pytorch_kinematics: 4 starts, batched, 1 CPU thread).
Float32 by default (what a user gets), float64 with `--x64` (the CLI runs in float32).
"""

import argparse
import importlib.util
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import results
from common import (
    TOL_POSITION,
    Goal,
    child_env,
    cold_compile_goal,
    first_and_second,
    fresh_process,
    goal,
    limits_tol,
    load_body,
    machine,
    not_measured,
    print_goals,
    select_device,
    start_run,
    timed,
    versions,
)

ARM_SEGMENTS = ("left_upper_arm", "left_forearm", "left_hand")
ARM_AND_CLAVICLE = ARM_SEGMENTS + ("left_clavicle",)
EFFECTOR = "left_hand.palm"
CLI_TARGET = (0.35, 0.3, 1.1)

GOAL_CLI_COLD_S = 3.0
GOAL_CLI_WARM_S = 1.0
GOAL_FIRST_CALL_S = 3.0
GOAL_WARM_S = 1e-3
GOAL_ARM_SUCCESS = 0.999
GOAL_PEER_RATIO = {"cpu": 10.0, "gpu": 10.0}
GOAL_BODY_SOLVES_PER_S = {"cpu": 5_000, "gpu": 200_000}
GOAL_ARM_SOLVES_PER_S_GPU = 2_000_000
SEEDS = {"arm": 0, "single": 1, "body": 2}  # of the targets (`palm_targets`)
GOAL_POSTURE_DEG = 2.0


# --- checking answers -----------------------------------------------------------------------
def _bent(body, pose):
    """The pose with its vertebrae bent to its spine target, as `forward` bends them."""
    import diffbody as db

    if pose.spine_target is None:
        return pose
    spine = body.spine
    out = db.bendspine(spine, spine.rest, pose.spine_target, initiator=spine.initiator)
    return db.with_spine_angles(body, spine, pose, out.angles)


def check(body, poses, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independently of the solver's own report: the palm's distance from its target (m) by
    `forward`, and the largest stop violation (rad, <= 0 inside the limits), of each of a
    batch of poses; at full float32 precision (a GPU's default matmul precision is lower)."""
    import diffbody as db

    palm = body.feature_index(EFFECTOR)

    def one(pose, xyz):
        error = jnp.linalg.norm(db.forward(body, pose).feature_points[palm] - xyz)
        return error, jnp.max(db.stop_violation(body, _bent(body, pose)))

    poses = jax.tree.map(jnp.asarray, poses)
    xyz = jnp.asarray(targets, body.lengths.dtype).reshape(-1, 3)
    with jax.default_matmul_precision("highest"):
        errors, violations = jax.jit(jax.vmap(one))(poses, xyz)
    return np.asarray(errors, np.float64), np.asarray(violations, np.float64)


@dataclass(frozen=True)
class Solved:
    """Answers to a batch of palm targets, checked by `check`."""

    errors: np.ndarray  # (n,) m: the palm's distance from the target
    violations: np.ndarray  # (n,) rad: largest stop violation
    reported: np.ndarray  # (n,) m: the solver's residual
    tol_limits: float

    @property
    def ok(self) -> np.ndarray:
        return (self.errors <= TOL_POSITION) & (self.violations <= self.tol_limits)

    @property
    def success(self) -> float:
        return float(np.mean(self.ok))

    def summary(self) -> str:
        mm = f"{TOL_POSITION * 1e3:g} mm"
        near = np.mean(self.errors <= TOL_POSITION)
        inside = np.mean(self.violations <= self.tol_limits)
        gap = np.max(np.abs(self.errors - self.reported))
        return (
            f"{self.success:.1%} within {mm} and limits ({near:.1%} within {mm}, median "
            f"{np.median(self.errors) * 1e3:.3f} mm, the solver's residual off by <= "
            f"{gap * 1e3:.1e} mm; {inside:.1%} within limits, largest stop violation "
            f"{np.max(self.violations):.1e} rad)"
        )


def checked(body, result, targets: np.ndarray, tol_limits: float | None = None) -> Solved:
    """A `ReachResult` of one palm target per row (batched, or one solve_reach result)."""
    reported = np.asarray(result.residuals, np.float64).reshape(-1)
    pose = result.pose
    if np.ndim(pose.position) == 1:
        pose = jax.tree.map(lambda x: jnp.asarray(x)[None], pose)
    errors, violations = check(body, pose, targets)
    tol = limits_tol() if tol_limits is None else tol_limits
    return Solved(errors, violations, reported, tol)


# --- 1. the command line ---------------------------------------------------------------------
@dataclass(frozen=True)
class CliRun:
    wall_s: float
    solved: Solved | None  # None: the command failed
    output: str


def _diffbody_command() -> list[str]:
    script = Path(sys.executable).with_name("diffbody")
    if script.exists():
        return [str(script)]
    found = shutil.which("diffbody")
    return [found] if found else [sys.executable, "-m", "diffbody"]


def run_cli(body, device: str, cache_dir: str, out_dir: str) -> CliRun:
    """The README's reach command, end to end, with JAX's compilation cache in `cache_dir`."""
    import diffbody as db

    out, png = Path(out_dir) / "reach.pose.json", Path(out_dir) / "reach.png"
    command = _diffbody_command() + ["reach", "--effector", EFFECTOR, "--target"]
    command += [str(x) for x in CLI_TARGET] + ["--out", str(out), "--png", str(png)]
    env = child_env(device)
    env["JAX_COMPILATION_CACHE_DIR"] = cache_dir
    env.pop("DIFFBODY_NO_CACHE", None)
    for path in (out, png):
        path.unlink(missing_ok=True)
    wall_s, proc = _run(command, env)
    if proc.returncode != 0 or not out.exists() or not png.exists():
        return CliRun(wall_s, None, proc.stdout + proc.stderr)
    data = json.loads(out.read_text())
    angles = np.radians([data["angles_deg"][name] for name in body.segment_names])
    spine = data["spine_target_deg"]
    pose = db.Pose(
        position=jnp.asarray(data["position"], body.lengths.dtype)[None],
        angles=jnp.asarray(angles, body.lengths.dtype)[None],
        spine_target=None if spine is None else jnp.asarray(np.radians(spine))[None],
    )
    # The command runs in float32 whatever this process does, and its JSON holds degrees.
    errors, violations = check(body, pose, np.asarray(CLI_TARGET))
    reported = np.asarray(data["residuals"]["targets"][:1], np.float64)
    return CliRun(
        wall_s, Solved(errors, violations, reported, limits_tol(jnp.float32)), proc.stdout
    )


def _run(command: list[str], env: dict[str, str]):
    """(wall seconds, the finished process)."""
    t0 = time.perf_counter()
    proc = subprocess.run(command, env=env, capture_output=True, text=True)
    return time.perf_counter() - t0, proc


# --- 2, 4, 5. compiles from cold ----------------------------------------------------------------
def palm_targets(body, count: int, seed: int) -> np.ndarray:
    """(count, 3) palm targets of random in-limit left-arm poses (module docstring)."""
    import peers

    rng = np.random.default_rng(seed)
    return peers.palm_positions(body, peers.arm_poses(body, count, rng))


def cold_child(kind: str, given: list, chunk_size: int | None) -> None:
    """In a fresh process (`common.fresh_process`): the first call of one entry point and a
    second identical one, printed with the answers' check as one JSON line. `kind` "reach":
    `solve_reach` on the whole body, `given` the target (x, y, z); "arm" or "body":
    `solve_reach_batch` on the left arm or the whole body, `given` (count, seed) of
    `palm_targets`."""
    import diffbody as db

    body = load_body()
    if kind == "reach":
        targets = np.asarray(given)
        out, first_s, second_s = first_and_second(
            lambda: db.solve_reach(body, [db.Target.position(EFFECTOR, targets)])
        )
        solved = checked(body, out, targets)
    else:
        segments = {"segments": ARM_SEGMENTS} if kind == "arm" else {}
        done = batch(body, palm_targets(body, *given), chunk_size, **segments)
        first_s, second_s, solved = done.first_s, done.run_s, done.solved
    line = dict(first_s=first_s, second_s=second_s, tol_limits=solved.tol_limits)
    for key in ("errors", "violations", "reported"):
        line[key] = getattr(solved, key).tolist()
    print(json.dumps(line))


def cold(args, kind: str, given, chunk_size: int | None) -> tuple[dict | None, Solved | None]:
    """(`cold_child`'s line, its answers checked) from a fresh process; (None, None) when it
    failed."""
    code = f"from ik import cold_child\ncold_child({kind!r}, {given!r}, {chunk_size!r})"
    line = fresh_process(code, args.device, args.x64)
    if line is None:
        return None, None
    parts = (np.asarray(line[k], np.float64) for k in ("errors", "violations", "reported"))
    return line, Solved(*parts, line["tol_limits"])


# --- 4, 5. batches ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Batch:
    """`solve_reach_batch` on palm targets: a first call, then a second identical one."""

    first_s: float
    run_s: float  # the second call
    solved: Solved
    result: object  # the ReachResult

    @property
    def compile_s(self) -> float:
        return self.first_s - self.run_s

    @property
    def solves_per_s(self) -> float:
        return len(self.solved.errors) / self.run_s


def batch(body, targets: np.ndarray, chunk_size: int | None, **kwargs) -> Batch:
    import diffbody as db

    def solve():
        return db.solve_reach_batch(
            body,
            [EFFECTOR],
            targets,
            chunk_size=chunk_size or 4096,
            progress=False,
            **kwargs,
        )

    out, first_s, run_s = first_and_second(solve)
    return Batch(first_s, run_s, checked(body, out, targets), out)


# --- 6. posture --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Posture:
    """How far answers moved what the arm alone could have reached without (degrees)."""

    spine_deg: np.ndarray  # (n, 3): |spine target - init's| (flexion, axial, lateral)
    swing_deg: np.ndarray  # (n, n_seg): swing change, 0 on the left arm and clavicle
    segment_names: tuple[str, ...]

    def over(self, limit: float) -> str:
        """How many answers move the spine target, or another segment, more than `limit`."""
        n = len(self.swing_deg)
        parts = [f"spine {np.sum(self.spine_deg.max(1) > limit)}"]
        parts.append(f"other segments {np.sum(self.swing_deg.max(1) > limit)}")
        worst = self.segment_names[int(np.argmax(self.swing_deg.max(0)))]
        return f"{', '.join(parts)} of {n} over {limit:g} deg (largest swing: {worst})"


def posture(body, poses) -> Posture:
    """Posture changes of answers (batched poses) from the standard position, their init."""
    import diffbody as db

    rest = body.rest_pose()
    init_sum = np.asarray(db.spine_angles(body, body.spine, rest).sum(0))
    if poses.spine_target is not None:
        totals = np.asarray(poses.spine_target)
    else:  # the spine as the angles hold it (a solve that left it alone)
        totals = np.asarray(
            jax.jit(
                jax.vmap(lambda a: db.spine_angles(body, body.spine, db.Pose(rest.position, a)))
            )(jnp.asarray(poses.angles)).sum(1)
        )
    spine_deg = np.degrees(np.abs(totals - init_sum))
    w0 = np.asarray(db.swing_vector(body, rest.angles))
    swing = jax.jit(jax.vmap(lambda a: db.swing_vector(body, a)))
    with jax.default_matmul_precision("highest"):
        w = np.asarray(swing(jnp.asarray(poses.angles)))
    change = np.degrees(np.linalg.norm(w - w0, axis=-1))  # (n, n_seg)
    change[:, [body.segment_index(s) for s in ARM_AND_CLAVICLE]] = 0.0
    return Posture(spine_deg, change, body.segment_names)


def stack(outs) -> object:
    return jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *outs)


# --- the run ---------------------------------------------------------------------------------
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--device", choices=("cpu", "gpu"), default="cpu", help="gpu: JAX's default backend"
    )
    results.add_arguments(parser)
    parser.add_argument("--n", type=int, default=None, help="arm targets (1,000; GPU 100,000)")
    parser.add_argument("--n-ikpy", type=int, default=None, help="of those, for IKPy (200)")
    parser.add_argument(
        "--n-body", type=int, default=None, help="whole-body batch (256; GPU 4,096)"
    )
    parser.add_argument("--repeats", type=int, default=None, help="warm single solves (20)")
    parser.add_argument("--chunk-size", type=int, default=None, help="4,096; GPU: the batch")
    parser.add_argument("--x64", action="store_true", help="run in float64")
    parser.add_argument(
        "--matmul-precision",
        choices=("default", "highest"),
        default="default",
        help="JAX's matmul precision (default: JAX's; on a GPU float32 products round to TF32)",
    )
    parser.add_argument("--skip-peers", action="store_true", help="no IKPy, pytorch_kinematics")
    parser.add_argument("--skip-cli", action="store_true", help="no command-line timings")
    parser.add_argument("--skip-fk", action="store_true", help="no forward-vs-MuJoCo figure")
    args = parser.parse_args()
    select_device(args.device, args.x64, args.matmul_precision)
    sys.stdout.reconfigure(line_buffering=True)
    gpu = args.device == "gpu"
    quick = args.quick
    if quick:  # a smoke run: no peers, no subprocesses
        args.skip_peers = args.skip_cli = args.skip_fk = True
    n = args.n or (100 if quick else 100_000 if gpu else 1_000)
    n_ikpy = args.n_ikpy if args.n_ikpy is not None else (10 if quick else 200)
    n_body = args.n_body or (16 if quick else 4_096 if gpu else 256)
    repeats = args.repeats or (5 if quick else 20)
    import diffbody as db

    body = load_body()
    print(machine())
    print(f"peers: {versions(['pytorch-kinematics', 'torch', 'ikpy', 'mujoco'])}")
    print(f"body: {body.name}, {body.n_segments} segments; targets: {EFFECTOR} of random")
    print(f"  in-limit poses of {', '.join(ARM_SEGMENTS)}; success: <= {TOL_POSITION * 1e3:g} mm")
    print(f"  and stop violation <= {limits_tol():g} rad")

    run_record = start_run(
        "ik",
        args,
        arm_targets=n,
        ikpy_targets=n_ikpy,
        body_targets=n_body,
        warm_repeats=repeats,
        seeds=SEEDS,
    )
    goals: list[Goal] = []
    speed_goals = {"cpu": "2-core CPU goals", "gpu": "GPU goals"}[args.device]

    # 1. the command line
    print(f"\n1. diffbody reach ... --target {' '.join(map(str, CLI_TARGET))} (subprocess)")
    cli_goals = (
        "README reach command (with --png), empty compile cache, wall",
        "README reach command (with --png), filled compile cache, wall",
    )
    if args.skip_cli:
        print("  skipped (--skip-cli)")
        goals += [not_measured(cli_goals[0], f"< {GOAL_CLI_COLD_S:.2f} s", "--skip-cli")]
        goals += [not_measured(cli_goals[1], f"< {GOAL_CLI_WARM_S:.2f} s", "--skip-cli")]
    else:
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out_dir:
            runs = [run_cli(body, args.device, cache, out_dir) for _ in range(2)]
        for name, run, limit in zip(cli_goals, runs, (GOAL_CLI_COLD_S, GOAL_CLI_WARM_S)):
            if run.solved is None:
                print(f"  {name}: FAILED after {run.wall_s:.2f} s:\n{run.output}")
                goals.append(Goal(name, "failed", f"< {limit:.2f} s", False))
                continue
            print(f"  {name}: {run.wall_s:.2f} s; {run.solved.summary()}")
            goals.append(
                goal(
                    name,
                    run.wall_s,
                    limit,
                    fmt=".2f",
                    unit=" s",
                    op="<",
                    success=run.solved.success,
                )
            )

    # 2, 3. whole-body solve_reach
    single = palm_targets(body, 1 + repeats, SEEDS["single"])
    print("\n2, 3. solve_reach, whole body (default unknowns), one palm target")
    goals += first_call_goals(args, single[0])

    def solve_one(xyz):
        return db.solve_reach(body, [db.Target.position(EFFECTOR, xyz)])

    _, here_s = timed(solve_one, single[0])
    runs = [timed(solve_one, xyz) for xyz in single[1:]]
    warm_s = statistics.median(t for _, t in runs)
    warm = checked(body, stack([out for out, _ in runs]), single[1:])
    print(f"  first call in this process: {here_s:.2f} s (compile + solve)")
    print(
        f"  warm: median {warm_s * 1e3:.2f} ms over {len(runs)} targets "
        f"(min {min(t for _, t in runs) * 1e3:.2f}, max {max(t for _, t in runs) * 1e3:.2f}); "
        f"{warm.summary()}"
    )
    goals.append(
        goal(
            f"solve_reach whole body, warm, median of {len(runs)}",
            warm_s * 1e3,
            GOAL_WARM_S * 1e3,
            fmt=".2f",
            unit=" ms",
            op="<",
            success=warm.success,
        )
    )

    # 4. the left arm, and the peers
    chunk = args.chunk_size or (max(n, n_body) if gpu else None)
    targets = palm_targets(body, n, SEEDS["arm"])
    print(f"\n4. solve_reach_batch, left arm ({', '.join(ARM_SEGMENTS)}), {n:,} targets")
    goals.append(batch_cold_goal(args, "arm", f"left arm, {n:,} targets", n, chunk))
    arm = batch(body, targets, chunk, segments=ARM_SEGMENTS)
    print(
        f"  in this process: first call {arm.first_s:.2f} s, second {arm.run_s:.3f} s -> "
        f"compile {arm.compile_s:.2f} s, {arm.solves_per_s:,.0f} solves/s; "
        f"{arm.solved.summary()}"
    )
    goals.append(
        goal(
            f"left arm, {n:,} targets, within 1 mm and limits",
            arm.solved.success * 100,
            GOAL_ARM_SUCCESS * 100,
            fmt=".1f",
            unit=" %",
        )
    )
    if gpu:
        goals.append(
            goal(
                f"left arm solves/s (batch {n:,})",
                arm.solves_per_s,
                GOAL_ARM_SOLVES_PER_S_GPU,
                fmt=",.0f",
                success=arm.solved.success,
            )
        )
    ratio_name = "left arm solves/s over pytorch_kinematics'"
    ratio_goal = GOAL_PEER_RATIO[args.device]
    if args.skip_peers:
        print("  peers skipped (--skip-peers)")
        goals.append(not_measured(ratio_name, f">= {ratio_goal:.1f}x", "--skip-peers"))
    else:
        peer_table = run_record.table(
            "peers",
            ["left arm", "targets", "setup (s)", "run (s)", "within 1 mm", "solves/s"],
            "lrrrrr",
        )
        goals.append(
            peer_figures(body, targets, n_ikpy, arm, gpu, ratio_name, ratio_goal, peer_table)
        )

    # 5. whole-body batch
    print(f"\n5. solve_reach_batch, whole body (default unknowns), {n_body:,} targets")
    goals.append(batch_cold_goal(args, "body", f"whole body, {n_body:,} targets", n_body, chunk))
    whole = batch(body, palm_targets(body, n_body, SEEDS["body"]), chunk)
    print(
        f"  in this process: first call {whole.first_s:.2f} s, second {whole.run_s:.3f} s -> "
        f"compile {whole.compile_s:.2f} s, {whole.solves_per_s:,.0f} solves/s; "
        f"{whole.solved.summary()}"
    )
    goals.append(
        goal(
            f"solve_reach_batch whole body, {n_body:,} targets, solves/s",
            whole.solves_per_s,
            GOAL_BODY_SOLVES_PER_S[args.device],
            fmt=",.0f",
            success=whole.solved.success,
        )
    )

    # 6. posture on arm-reachable targets
    poses = [stack([out.pose for out, _ in runs]), whole.result.pose]
    moved = posture(body, jax.tree.map(lambda *a: np.concatenate(a), *poses))
    print(f"\n6. posture: the {len(moved.swing_deg)} whole-body answers of 3 and 5")
    print(f"  (init: the standard position); {moved.over(GOAL_POSTURE_DEG)}")
    spine_name = "arm-reachable targets: max |spine target - init's| (deg)"
    largest = moved.spine_deg.max(0)
    components = ", ".join(f"{a:.2f}" for a in largest)
    print(f"  largest spine target change (flexion, axial, lateral): {components} deg")
    goals.append(goal(spine_name, float(largest.max()), GOAL_POSTURE_DEG, fmt=".2f", op="<="))
    swing = float(moved.swing_deg.max())
    print(f"  largest swing change off the left arm and clavicle: {swing:.2f} deg")
    goals.append(
        goal(
            "arm-reachable targets: max swing change off left arm + clavicle (deg)",
            swing,
            GOAL_POSTURE_DEG,
            fmt=".2f",
            op="<=",
        )
    )

    # 7. forward against MuJoCo
    print("\n7. forward, full body, against MuJoCo")
    from fk import GOAL_MUJOCO_RATIO, MUJOCO_FIGURE, mujoco_comparison, print_comparison

    mujoco_missing = not _importable("mujoco")
    if args.skip_fk or mujoco_missing:
        why = "--skip-fk" if args.skip_fk else "mujoco not installed"
        print(f"  skipped ({why})")
        goals.append(not_measured(MUJOCO_FIGURE, f">= {GOAL_MUJOCO_RATIO:.1f}x", why))
    else:
        comparison = mujoco_comparison(
            body, 10_000 if quick else 100_000, 1_000 if quick else 10_000, 3 if quick else 5
        )
        print_comparison(comparison)
        goals.append(comparison.goal())

    dtype = "float64" if args.x64 else "float32"
    title = f"goals ({speed_goals}; diffbody on {args.device}, {dtype}"
    print_goals(goals, title + (", --quick: small batches" if quick else "") + ")")
    run_record.add_goals(goals)
    run_record.write(results.out_dir(args.out, quick))


def first_call_goals(args, xyz) -> list[Goal]:
    """Goal 2: `solve_reach`'s first call in a fresh process without the compilation cache,
    and its compile from cold (the first call minus a second identical one)."""
    name, entry = "solve_reach whole body, first call (fresh process)", "solve_reach whole body"
    if args.quick:
        why = "--quick"
        return [
            not_measured(name, f"< {GOAL_FIRST_CALL_S:.2f} s", why),
            cold_compile_goal(entry, None, why),
        ]
    line, solved = cold(args, "reach", [float(x) for x in xyz], None)
    if line is None:
        failed = Goal(name, "failed", f"< {GOAL_FIRST_CALL_S:.2f} s", False)
        return [failed, cold_compile_goal(entry, None)]
    print(f"  first call in a fresh process: {line['first_s']:.2f} s; {solved.summary()}")
    first = goal(
        name,
        line["first_s"],
        GOAL_FIRST_CALL_S,
        fmt=".2f",
        unit=" s",
        op="<",
        success=solved.success,
    )
    return [first, cold_compile_goal(entry, line, success=solved.success)]


def batch_cold_goal(args, kind: str, what: str, count: int, chunk: int | None) -> Goal:
    """Goals 4, 5: `solve_reach_batch`'s compile from cold on `count` targets of `kind`'s
    seed ("arm": the left arm; "body": the whole body), in a fresh process."""
    entry = f"solve_reach_batch {what}"
    if args.quick:
        return cold_compile_goal(entry, None, "--quick")
    line, solved = cold(args, kind, [count, SEEDS[kind]], chunk)
    return cold_compile_goal(entry, line, success=None if solved is None else solved.success)


def _importable(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def peer_figures(
    body, targets, n_ikpy: int, arm: Batch, gpu: bool, name: str, ratio_goal: float, table
):
    """pytorch_kinematics (and IKPy, CPU runs only) on the arm targets, each a row of
    `table`; the ratio's Goal."""
    import peers

    if not _importable("pytorch_kinematics"):
        print("  pytorch_kinematics not installed (pip install -e '.[bench]')")
        return not_measured(name, f">= {ratio_goal:.1f}x", "pytorch_kinematics not installed")
    import torch

    device = "cuda" if gpu else "cpu"
    if gpu and not torch.cuda.is_available():
        print("  torch has no CUDA device: pytorch_kinematics not measured")
        return not_measured(name, f">= {ratio_goal:.1f}x", "no torch CUDA")
    with tempfile.TemporaryDirectory() as directory:
        chain = peers.arm_chain(body, directory)
        seed_q = peers.rest_joint_values(body, chain)
        solved = [peers.solve_pytorch_kinematics(chain, targets, seed_q, device=device)]
        if n_ikpy and not gpu and _importable("ikpy"):
            solved.append(peers.solve_ikpy(chain, targets[:n_ikpy], seed_q))
    print(f"  {'':<20} {'targets':>8} {'setup s':>8} {'run s':>8} {'<=1mm':>7} {'solves/s':>10}")
    print(
        f"  {'diffbody':<20} {len(targets):>8,} {arm.compile_s:>8.2f} {arm.run_s:>8.3f} "
        f"{np.mean(arm.solved.errors <= TOL_POSITION):>7.1%} {arm.solves_per_s:>10,.0f}"
    )
    for r in solved:
        print(
            f"  {r.name:<20} {len(r.errors):>8,} {r.setup_s:>8.2f} {r.run_s:>8.3f} "
            f"{r.success(TOL_POSITION):>7.1%} {r.solves_per_s:>10,.0f}"
        )
    table.add(
        "diffbody",
        f"{len(targets):,}",
        f"{arm.compile_s:.1f}",
        f"{arm.run_s:.3g}",
        f"{np.mean(arm.solved.errors <= TOL_POSITION):.1%}",
        f"{arm.solves_per_s:,.0f}",
    )
    for r in solved:
        table.add(
            f"{r.name} {r.version}",
            f"{len(r.errors):,}",
            f"{r.setup_s:.1f}",
            f"{r.run_s:.3g}",
            f"{r.success(TOL_POSITION):.1%}",
            f"{r.solves_per_s:,.0f}",
        )
    for r in solved:
        print(f"  {r.name} {r.version}: {r.settings}")
    print(
        "  (peers: success within 1 mm only; their URDF limits are boxes, looser than diffbody's)"
    )
    pk = solved[0]
    return goal(
        f"{name} ({arm.solves_per_s:,.0f} against {pk.solves_per_s:,.0f}/s, {pk.name} on {device})",
        arm.solves_per_s / pk.solves_per_s,
        ratio_goal,
        fmt=".1f",
        unit="x",
        success=arm.solved.success,
    )


if __name__ == "__main__":
    main()
