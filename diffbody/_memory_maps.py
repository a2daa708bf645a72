"""Linux's limit on a process's memory maps, and XLA's compiled programs (docs/design.md,
"Around the core").

XLA's CPU compiler maps each compiled program's code into memory, about six maps a program,
and JAX keeps every program it compiled for as long as its caches hold it. A long-lived
process that compiles many thousands of programs (a notebook, a test worker) reaches the
kernel's limit (`vm.max_map_count`, 65,530 by default); the next compile then fails inside
LLVM ("LLVM compilation error: Cannot allocate memory") and the process dies of SIGSEGV.

diffbody watches the count after compiles (JAX's compile event) and, near the limit, empties
JAX's caches: the programs are compiled again when next used (from the persistent cache
where it is on), a RuntimeWarning says so once, and the process lives. Raising the limit
(`sysctl -w vm.max_map_count=262144`) avoids the recompiles.
"""

import gc
import warnings
from pathlib import Path

import jax

BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
MAPS, LIMIT = Path("/proc/self/maps"), Path("/proc/sys/vm/max_map_count")
NEAR = 0.9  # of the limit: the caches are emptied beyond it
EVERY = 16  # compiles between two counts (a count reads every map: ~10 ms at the limit)


def memory_maps() -> tuple[int, int] | None:
    """(memory maps of this process, the kernel's limit), or None where Linux's /proc is not."""
    try:
        with MAPS.open("rb") as maps:
            count = sum(1 for _ in maps)
        return count, int(LIMIT.read_text())
    except (OSError, ValueError):
        return None


class _Watch:
    """JAX's compile listener: every `EVERY` compiles, the caches emptied when the count is
    beyond `NEAR` of the limit."""

    def __init__(self):
        self.compiles = 0
        self.warned = False

    def __call__(self, event: str, duration: float, **kwargs) -> None:
        if event != BACKEND_COMPILE:
            return
        self.compiles += 1
        if self.compiles % EVERY:
            return
        counted = memory_maps()
        if counted is None or counted[0] < NEAR * counted[1]:
            return
        # Called after the compile has returned its program: emptying the caches here drops
        # the programs no one holds; the caller still holds the one just compiled.
        jax.clear_caches()
        gc.collect()
        if not self.warned:
            self.warned = True
            warnings.warn(
                f"this process held {counted[0]} memory maps of the {counted[1]} Linux allows "
                "(vm.max_map_count), most of them compiled programs: JAX's caches were emptied "
                "so that the next compile does not crash, and programs compile again when next "
                "used. Raise the limit (sysctl -w vm.max_map_count=262144) to keep them.",
                RuntimeWarning,
                stacklevel=2,
            )


WATCH = _Watch()
jax.monitoring.register_event_duration_secs_listener(WATCH)
