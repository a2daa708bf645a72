"""Near Linux's memory-map limit XLA's CPU compiler crashes (SIGSEGV or std::bad_alloc);
diffbody empties JAX's caches first (diffbody._memory_maps). The reproducer fills a process's
maps to the limit with pages of its own and then compiles: without diffbody it dies, with it it
lives."""

import os
import signal
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import pytest

from diffbody import _memory_maps
from diffbody._memory_maps import BACKEND_COMPILE, EVERY, _Watch, memory_maps


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux's /proc")
def test_memory_maps_counts_this_process():
    count, limit = memory_maps()
    assert 0 < count < limit
    pages = [jax.jit(lambda x, i=i: x * i)(jnp.ones(i + 3)) for i in range(20)]
    assert memory_maps()[0] > count  # each compiled program maps its code
    assert len(pages) == 20


@pytest.fixture
def quiet_watch():
    """The process's own watch unregistered: it reads the same (patched) `memory_maps` and,
    at a multiple of EVERY compiles in this worker, would empty the caches and warn
    during the test (a flake that depended on what the worker compiled before)."""
    jax.monitoring.unregister_event_duration_listener(_memory_maps.WATCH)
    try:
        yield
    finally:
        jax.monitoring.register_event_duration_secs_listener(_memory_maps.WATCH)


def test_the_watch_empties_the_caches_near_the_limit_and_warns_once(monkeypatch, quiet_watch):
    f = jax.jit(lambda x: x + 1)
    f(1.0)
    assert f._cache_size() == 1
    watch = _Watch()
    monkeypatch.setattr(_memory_maps, "memory_maps", lambda: (89, 100))  # below NEAR
    for _ in range(EVERY):
        watch(BACKEND_COMPILE, 0.1)
    assert f._cache_size() == 1
    monkeypatch.setattr(_memory_maps, "memory_maps", lambda: (95, 100))
    for _ in range(EVERY - 1):
        watch(BACKEND_COMPILE, 0.1)
        watch("/jax/core/compile/jaxpr_trace_duration", 0.1)  # other events are not compiles
    assert f._cache_size() == 1  # counted every EVERY compiles only
    with pytest.warns(RuntimeWarning, match="95 memory maps of the 100"):
        watch(BACKEND_COMPILE, 0.1)
    assert f._cache_size() == 0
    f(1.0)
    for _ in range(EVERY):
        watch(BACKEND_COMPILE, 0.1)  # emptied again, without a second warning
    assert f._cache_size() == 0
    monkeypatch.setattr(_memory_maps, "memory_maps", lambda: None)  # no /proc: nothing
    for _ in range(EVERY):
        watch(BACKEND_COMPILE, 0.1)


FILL_AND_COMPILE = textwrap.dedent(
    """
    import ctypes, mmap, sys, warnings
    import jax, jax.numpy as jnp
    if sys.argv[1] == "diffbody":
        import diffbody
    warnings.simplefilter("ignore")
    libc = ctypes.CDLL(None)
    libc.mmap.restype = ctypes.c_void_p
    libc.mmap.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int,
                          ctypes.c_int, ctypes.c_long]
    jax.jit(jnp.sin)(1.0)
    with open("/proc/self/maps", "rb") as f:
        count = sum(1 for _ in f)
    limit = int(open("/proc/sys/vm/max_map_count").read())
    # pages that cannot merge (alternating protection), up to 300 maps below the limit
    for n in range(limit - 300 - count):
        prot = mmap.PROT_READ if n % 2 else mmap.PROT_READ | mmap.PROT_WRITE
        libc.mmap(None, 4096, prot, mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS, -1, 0)
    jax.jit(jnp.cos)(1.0)
    with open("/proc/self/maps", "rb") as f:
        count = sum(1 for _ in f)
    # diffbody's watch counts every 16 compiles: it starts within reach of the limit
    for i in range(300):
        jax.jit(lambda x, i=i: jnp.sin(x) * i + jnp.cos(x) ** 2)(jnp.ones(i + 1))
    print("lived")
    """
)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux's memory-map limit")
@pytest.mark.parametrize("imports, lives", [("jax", False), ("diffbody", True)])
def test_compiles_at_the_limit_crash_without_diffbody_and_live_with_it(imports, lives):
    env = dict(os.environ, JAX_ENABLE_X64="0", JAX_COMPILATION_CACHE_DIR="")
    run = subprocess.run(
        [sys.executable, "-c", FILL_AND_COMPILE, imports],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    if lives:
        assert run.returncode == 0 and "lived" in run.stdout, run.stderr[-3000:]
    else:
        # XLA fails either way at the limit: LLVM's mmap fails and the process segfaults, or
        # an allocation throws std::bad_alloc, raised in Python as MemoryError (seen on CI).
        assert "lived" not in run.stdout
        died = run.returncode == -signal.SIGSEGV and "Cannot allocate memory" in run.stderr
        raised = run.returncode == 1 and "MemoryError: std::bad_alloc" in run.stderr
        assert died or raised, (run.returncode, run.stderr[-3000:])
