"""What every benchmark prints and how it times: machine and versions, compile time apart
from the median run time, compiles from cold in a fresh process, and the goals table (each
figure beside its goal, met or not)."""

import importlib.metadata
import json
import os
import platform
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
from results import Run

TOL_POSITION = 1e-3  # m: what counts as reached
# Joint limits hold when every stop violation is <= 256 eps of the dtype (rad): float32
# rounding puts poses on a limit, the standard position included, up to ~40 eps outside.
# The default tolerance of `diffbody.within_limits`.
LIMITS_EPS = 256
SUCCESS_FOR_SPEED = 0.999  # a speed figure counts only at this success rate
# s: every public entry point's compile from cold (reach, batch, mocap, cloud fit, lifting),
# the first call minus a second identical one in a fresh process (`fresh_process`).
GOAL_COLD_COMPILE_S = 5.0
BENCHMARKS = os.path.dirname(os.path.abspath(__file__))


def select_device(device: str, x64: bool = False, precision: str = "default") -> None:
    """Run JAX on `device` ("cpu", or "gpu": JAX's default backend, which must be a GPU),
    with float64 if `x64`, and matmuls at `precision` ("default": JAX's, which on a GPU
    rounds float32 products to TF32; "highest": full float32); call before JAX has started
    a backend."""
    if x64:
        jax.config.update("jax_enable_x64", True)
    if precision != "default":
        jax.config.update("jax_default_matmul_precision", precision)
    if device == "cpu":
        jax.config.update("jax_platforms", "cpu")
    elif jax.default_backend() != "gpu":
        raise SystemExit(f"--device gpu: JAX's default backend is {jax.default_backend()!r}")


def child_env(device: str) -> dict[str, str]:
    """The environment of a subprocess that should run JAX as we do (device, precision)."""
    env = dict(os.environ)
    if jax.config.jax_default_matmul_precision:
        env["JAX_DEFAULT_MATMUL_PRECISION"] = str(jax.config.jax_default_matmul_precision)
    if device == "cpu":
        env["JAX_PLATFORMS"] = "cpu"
    else:  # this process already holds most of the GPU's memory
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    return env


def versions(packages: list[str]) -> str:
    """'name version, ...' of installed distributions (missing ones say so)."""

    def one(p: str) -> str:
        try:
            return f"{p} {importlib.metadata.version(p)}"
        except importlib.metadata.PackageNotFoundError:
            return f"{p} (not installed)"

    return ", ".join(one(p) for p in packages)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    dev = jax.devices()[0]
    return (
        f"machine: {cpu}, {os.cpu_count()} cores, device {dev.platform}:{dev.device_kind}\n"
        f"versions: python {platform.python_version()}, jax {jax.__version__}, "
        f"numpy {np.__version__}, dtype {'float64' if jax.config.jax_enable_x64 else 'float32'} "
        f"(matmul precision {jax.config.jax_default_matmul_precision or 'default'}), "
        f"{versions(['diffbody', 'optimistix', 'equinox', 'lineax'])}"
    )


def start_run(benchmark: str, args, **conditions) -> Run:
    """The record of this run (`results.Run`): the command as typed (without --out), the
    machine and versions, `conditions` (sizes, seeds, spreads) and --quick."""
    argv = sys.argv[1:]
    if "--out" in argv:  # `--out DIR`: where it wrote is not what it measured
        i = argv.index("--out")
        argv = argv[:i] + argv[i + 2 :]
    argv = [a for a in argv if not a.startswith("--out=")]
    where, what = machine().split("\n")
    return Run(
        benchmark,
        command=" ".join(["python", f"benchmarks/{Path(sys.argv[0]).name}", *argv]),
        machine=where.removeprefix("machine: "),
        versions=what.removeprefix("versions: "),
        conditions=conditions,
        quick=bool(getattr(args, "quick", False)),
    )


def load_body(**kwargs):
    """`diffbody.load_body`, its arrays in JAX's default float type (float32 unless x64)."""
    import diffbody as db

    dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    body = db.load_body(**kwargs)
    return jax.tree.map(lambda x: x.astype(dtype) if isinstance(x, jax.Array) else x, body)


def limits_tol(dtype=None) -> float:
    """rad: the stop violation up to which a pose counts as within the limits (`dtype`:
    default JAX's float type)."""
    dtype = dtype or (jnp.float64 if jax.config.jax_enable_x64 else jnp.float32)
    return LIMITS_EPS * float(jnp.finfo(dtype).eps)


def ms(seconds: float) -> str:
    """Milliseconds as a table shows them: three significant digits, whole numbers above 100."""
    x = seconds * 1e3
    return f"{x:,.0f}" if x >= 100 else f"{x:.3g}"


def timed(fn, *args, **kwargs):
    """(fn's result, once ready; wall seconds)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - t0


def first_and_second(fn) -> tuple[object, float, float]:
    """(fn()'s result, seconds of the first call, seconds of a second identical call): their
    difference is what the first call spent tracing and compiling."""
    out, first_s = timed(fn)
    _, second_s = timed(fn)
    return out, first_s, second_s


def fresh_process(code: str, device: str, x64: bool = False) -> dict | None:
    """Run Python `code` in a fresh process, JAX on `device` (`select_device`) with an
    empty compilation cache of its own (as a new install has: XLA's cache and diffbody's
    exported programs, `_programs`), so that every compile starts from nothing; the JSON
    object its last output line holds (`print_first_and_second`), or None when it failed
    (its output printed). Regression: with JAX's cache merely switched off, diffbody still
    read the exported programs an earlier run had kept in the user's cache, and skipped
    their tracing."""
    prologue = (
        f"import sys\nsys.path.insert(0, {BENCHMARKS!r})\nfrom common import select_device\n"
        f"select_device({device!r}, x64={x64!r})\n"
    )
    env = child_env(device)
    empty = tempfile.mkdtemp(prefix="diffbody-cold-")
    env["JAX_COMPILATION_CACHE_DIR"] = empty
    # From benchmarks/, as this process runs: the same diffbody (not one a folder holds).
    try:
        proc = subprocess.run(
            [sys.executable, "-c", prologue + code],
            env=env,
            cwd=BENCHMARKS,
            capture_output=True,
            text=True,
        )
    finally:
        shutil.rmtree(empty, ignore_errors=True)
    try:
        return json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        output = (proc.stdout + proc.stderr)[-3000:]
        print(f"  the fresh process failed (exit status {proc.returncode}):\n{output}")
        return None


def print_first_and_second(fn, **extra) -> None:
    """In a fresh process: time fn's first call and a second identical one, and print
    {"first_s", "second_s", **extra} as one JSON line (what `fresh_process` returns)."""
    _, first_s, second_s = first_and_second(fn)
    print(json.dumps({"first_s": first_s, "second_s": second_s, **extra}))


def bench(fn, args, repeats: int) -> tuple[float, float]:
    """(compile seconds, median run seconds) of jit(fn) on args, after one warm-up run."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))  # warm up
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        runs.append(time.perf_counter() - t0)
    return compile_s, statistics.median(runs)


@dataclass(frozen=True)
class Goal:
    """One figure beside its goal. `met` is None when the figure was not measured."""

    figure: str
    measured: str
    goal: str
    met: bool | None
    success: str = ""  # the success rate a speed figure was taken at ("" where none applies)


def goal(
    figure: str,
    value: float,
    target: float,
    *,
    fmt: str,
    unit: str = "",
    op: str = ">=",
    success: float | None = None,
) -> Goal:
    """A Goal for a number: met when `value op target` (op ">=", "<" or "<="), and, when a
    `success` fraction is given (speed figures), only at >= SUCCESS_FOR_SPEED of it."""
    compare = {">=": np.greater_equal, "<": np.less, "<=": np.less_equal}[op]
    met = bool(np.isfinite(value) and compare(value, target))
    if success is not None:
        met = met and success >= SUCCESS_FOR_SPEED
    shown = "" if success is None else f"{success:.1%}"
    return Goal(figure, f"{value:{fmt}}{unit}", f"{op} {target:{fmt}}{unit}", met, shown)


def not_measured(figure: str, goal_text: str, why: str) -> Goal:
    return Goal(figure, f"({why})", goal_text, None)


def cold_compile_goal(
    entry: str, child: dict | None, why: str = "", success: float | None = None
) -> Goal:
    """The Goal of `entry`'s compile from cold: `child` is what `fresh_process` returned
    (None: it failed), its first call minus its second < GOAL_COLD_COMPILE_S; `why` says why
    it was not measured (--quick, ...); `success` as for `goal`."""
    figure = f"{entry}: compile from cold (fresh process, no compilation cache)"
    limit = f"< {GOAL_COLD_COMPILE_S:.2f} s"
    if why:
        return not_measured(figure, limit, why)
    if child is None:
        return Goal(figure, "failed", limit, False)
    compile_s = child["first_s"] - child["second_s"]
    print(
        f"  {entry} from cold: first call {child['first_s']:.2f} s, second "
        f"{child['second_s']:.3f} s -> compile {compile_s:.2f} s"
    )
    return goal(
        figure, compile_s, GOAL_COLD_COMPILE_S, fmt=".2f", unit=" s", op="<", success=success
    )


def print_goals(goals: list[Goal], title: str, success: str = "") -> None:
    """The goals table: figure, measured, success rate, goal, met / not met. `success` says
    what the success column counts (default: targets reached within the limits); the line
    is left out when no figure has a success rate."""
    print(f"\n{title}")
    success = success or (f"targets within {TOL_POSITION * 1e3:g} mm and within the joint limits")
    if any(g.success for g in goals):
        print(
            f"  figures with a success column count only at >= {SUCCESS_FOR_SPEED:.1%} "
            f"success: {success}"
        )
    header = ("figure", "measured", "success", "goal", "met / not met")
    w = (
        max(len(header[0]), *(len(g.figure) for g in goals)),
        max(len(header[1]), *(len(g.measured) for g in goals)),
        7,
        max(len(header[3]), *(len(g.goal) for g in goals)),
    )
    print(
        f"  {header[0]:<{w[0]}}  {header[1]:>{w[1]}}  {header[2]:>{w[2]}}  "
        f"{header[3]:>{w[3]}}  {header[4]}"
    )
    print(f"  {'-' * w[0]}  {'-' * w[1]}  {'-' * w[2]}  {'-' * w[3]}  {'-' * len(header[4])}")
    for g in goals:
        met = "not measured" if g.met is None else ("met" if g.met else "not met")
        print(
            f"  {g.figure:<{w[0]}}  {g.measured:>{w[1]}}  {g.success:>{w[2]}}  "
            f"{g.goal:>{w[3]}}  {met}"
        )
    counted = [g for g in goals if g.met is not None]
    print(f"  {sum(g.met for g in counted)} of {len(counted)} measured goals met")
