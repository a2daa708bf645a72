"""What every benchmark prints and how it times: machine and versions, compile time apart
from the median run time."""

import os
import platform
import statistics
import time

import jax
import numpy as np


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
        f"numpy {np.__version__}, dtype {'float64' if jax.config.jax_enable_x64 else 'float32'}"
    )


def bench(fn, args, repeats: int) -> tuple[float, float]:
    """(compile seconds, median run seconds)."""
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
