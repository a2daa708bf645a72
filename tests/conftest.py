"""Strict test configuration: float64 everywhere, shared bodies and compiled functions.

Two tiers: the default `pytest` runs every unit, property, derivative and reference test; the
`slow` marker (`pytest -m slow`) holds the runs that repeat them for documentation's sake
(notebooks, the README's and guide's code, benchmark smoke runs) and the tests that need
processes of their own (signals, several processes). The default tier compiles at XLA's
cheapest optimisation level; the slow tier compiles as users do.
"""

import os
import tempfile
from pathlib import Path

import jax
import pytest
from hypothesis import HealthCheck, settings

import diffbody as db
from diffbody._memory_maps import memory_maps
from diffbody._programs import CPU_OPTIONS

os.environ.setdefault("MPLBACKEND", "Agg")


def _cache_dir() -> str:
    """The suite's persistent compilation cache: kept across runs on one machine, under the
    user's cache directory, one per JAX version (a new JAX compiles anew). Set
    JAX_COMPILATION_CACHE_DIR to use another (an empty folder measures a cold run)."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return str(base / "diffbody" / f"tests-jax-{jax.__version__}")


# One persistent cache, shared by the pytest-xdist workers, the notebooks' kernels and the
# command-line subprocesses (they inherit this environment): what one compiled, the others
# read back. Every program is cached, however quickly it compiled: a process still traces
# and lowers what it runs, but XLA's share of the hundreds of small programs is saved.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _cache_dir())
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

# The unit tests' programs are compiled far more often than they run long: XLA's cheapest
# optimisation level halves the compile time of a solver (the sphere-cloud fit: 100 s ->
# 45 s on one core) for a few times its run time (0.5 s -> 2 s). Results are the same to
# rounding. The slow tier, benchmarks and users keep the default level.
# With the options diffbody's own solve programs compile with (`_programs.CPU_OPTIONS`: no CPU
# fusion emitters) for every program of the tier, which then compiles about a sixth faster; the
# answers are the same to rounding (tests/test_programs.py compares a round with and without).
TEST_XLA_FLAGS = (
    "--xla_backend_optimization_level=0",
    "--xla_llvm_disable_expensive_passes=true",
    *(f"--{name}={str(value).lower()}" for name, value in CPU_OPTIONS.items()),
)


# A worker that dies says where: Python's fault handler prints every thread's stack on a
# fatal signal, and each worker notes the test it is running with its memory, which the
# controller prints when the worker goes down (`pytest_testnodedown`).
os.environ.setdefault("PYTHONFAULTHANDLER", "1")
WORKERS = Path(os.environ.setdefault("DIFFBODY_TEST_WORKERS", tempfile.mkdtemp(prefix="diffbody-")))


def _memory() -> str:
    """This process's resident memory and memory maps (Linux), for a crash report."""
    try:
        rss = next(ln for ln in Path("/proc/self/status").read_text().splitlines() if "VmRSS" in ln)
        maps = len(Path("/proc/self/maps").read_text().splitlines())
        limit = Path("/proc/sys/vm/max_map_count").read_text().strip()
    except (OSError, StopIteration):
        return "memory unknown"
    return f"{' '.join(rss.split()[1:])} resident, {maps} memory maps of {limit} allowed"


def pytest_runtest_logstart(nodeid, location):
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker:  # in the worker that runs the test
        (WORKERS / worker).write_text(f"{nodeid} ({_memory()} as it began)")


def pytest_runtest_teardown(item):
    """A worker past half the kernel's memory-map limit empties JAX's caches between two
    tests (diffbody._memory_maps: near the limit XLA's compiler crashes), before the
    library's own watch would, which warns."""
    counted = memory_maps()
    if counted is not None and counted[0] > counted[1] // 2:
        jax.clear_caches()


def pytest_testnodedown(node, error):
    """In the controller: a worker that crashed, with the test it was running and its memory."""
    if error:
        status = WORKERS / node.gateway.id
        what = status.read_text() if status.exists() else "no test begun"
        reporter = node.config.pluginmanager.get_plugin("terminalreporter")
        reporter.write_line(f"worker {node.gateway.id} crashed: {error}; it was running {what}")


def _slow_tier(config) -> bool:
    """Whether this run selects the slow tier alone (`-m slow`)."""
    return config.getoption("markexpr", "").strip() == "slow"


def pytest_configure(config):
    # Before any computation: XLA reads its flags when the CPU backend starts.
    if not _slow_tier(config):
        flags = [os.environ.get("XLA_FLAGS", ""), *TEST_XLA_FLAGS]
        os.environ["XLA_FLAGS"] = " ".join(f for f in flags if f)
    jax.config.update("jax_enable_x64", True)


settings.register_profile(
    "diffbody",
    deadline=None,
    max_examples=60,
    derandomize=True,  # reproducible in CI
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("diffbody")


@pytest.fixture(scope="session")
def male50() -> db.Body:
    return db.load_body(variant="male50")


@pytest.fixture(scope="session")
def female50() -> db.Body:
    return db.load_body(variant="female50")


@pytest.fixture(scope="session")
def fk_male50(male50):
    """forward for the male50 body, compiled once for the whole session."""
    return jax.jit(lambda pose: db.forward(male50, pose))


# The files that take longest (measured: tens of seconds to minutes on 2 cores, most of it
# compiling), longest first: scheduled first, so that the two workers finish together
# instead of one waiting on a long file collected last. The notebooks and the README lead
# the slow tier.
LONGEST = (
    "test_notebooks.py",
    "test_readme.py",
    "test_mocap.py",
    "test_cloud_fit.py",
    "test_constraints.py",
    "test_reach.py",
    # After test_cloud_fit.py, whose `fit` command compiles the program it fits on (read back
    # from the persistent cache, not compiled twice at once).
    "test_cloud_start.py",
    "test_reach_programs.py",
    "test_tree.py",
    "test_cli_mocap_trials.py",
    "test_points.py",
    "test_cli_mocap.py",
    "test_lifting.py",
    "test_kinematics.py",
    "test_export.py",
    "test_anthropometry.py",
    "test_programs.py",
    "test_webb.py",
    "test_spine.py",
    "test_posture.py",
    "test_cli_batch_stream.py",
    "test_views.py",
    "test_joint_angles.py",
)


def pytest_collection_modifyitems(items):
    def rank(item) -> int:
        name = item.nodeid.split("::")[0].split("/")[-1]
        return LONGEST.index(name) if name in LONGEST else len(LONGEST)

    items.sort(key=rank)  # stable: within a file, and among the rest, as collected
