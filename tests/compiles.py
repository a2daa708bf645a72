"""Counting what XLA compiles, for the tests that say a setting is data (one program)."""

import contextlib
import logging

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


class _Names(logging.Handler):
    def __init__(self):
        super().__init__()
        self.names: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if message.startswith("Compiling jit("):
            self.names.append(message[len("Compiling jit(") :].split(")")[0])


@contextlib.contextmanager
def compiled_names():
    """The names of the programs JAX compiles (or reads back from the persistent cache)
    inside the block, as a list that fills as they happen."""
    handler = _Names()
    logger = logging.getLogger("jax")
    logger.addHandler(handler)
    try:
        with jax.log_compiles():
            yield handler.names
    finally:
        logger.removeHandler(handler)
