"""Counting what XLA compiles, for the tests that say a setting is data (one program)."""

import contextlib

import jax

COMPILE = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def counted_compiles():
    """The XLA compiles inside the block, as a list that fills as they happen."""
    seen: list[float] = []

    def listen(event: str, secs: float, **_) -> None:
        if event == COMPILE:
            seen.append(secs)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield seen
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
