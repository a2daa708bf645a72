"""Long runs that lose nothing: a results CSV appended one finished chunk at a time, begun
with `#` header lines that say what produced it (so a rerun can check it goes on with the
same work), and SIGINT / SIGTERM turned into a clean stop between chunks.

The file's layout (one CSV dialect; a reader skips the `#` lines, as
``csv.DictReader(line for line in f if not line.startswith("#"))`` or pandas'
``read_csv(path, comment="#")`` do)::

    # key: value          one line per header field, in order
    col,col,...           the column names
    cell,cell,...         the rows, whole lines only

Each chunk's rows go to the file in one write, then flush and fsync: a killed process leaves
at most a final partial line, which `read_results` does not count.
"""

import _thread
import csv
import hashlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM during a run under `Interrupts`: a KeyboardInterrupt (so that no
    `except Exception` on the way swallows it, and a notebook stops as on Ctrl-C). A run
    that kept its finished chunks raises it again with `done` of `total` rows (or trials)
    and the file `out` that holds them, and says so."""

    def __init__(self, signum: int, done: int = 0, total: int = 0, out: str | None = None):
        super().__init__(signum, done, total, out)
        self.signum, self.done, self.total, self.out = signum, done, total, out

    @property
    def code(self) -> int:
        """The shell's exit status of a process ended by the signal: 128 + its number."""
        return 128 + self.signum

    def __str__(self) -> str:
        if self.out is None:
            return f"interrupted by signal {self.signum}"
        return (
            f"interrupted after {self.done} of {self.total} rows; {self.out} holds them; "
            "call again with resume=True (the command line: --resume)"
        )


class Interrupts:
    """While entered, SIGINT and SIGTERM raise `Interrupted` in the main thread wherever it
    is (the chunk in flight is dropped), except inside `held()`: there the signal is noted
    and raised when the block ends, so a chunk being written is written whole. Once one
    signal is taken, further ones are ignored (a second Ctrl-C does not break the clean
    stop). An `Interrupted` that Python drops (raised in a gc callback) is raised again. The
    previous handlers come back on exit. Outside the main thread (where Python cannot set
    handlers) it does nothing."""

    def __enter__(self) -> "Interrupts":
        self._old: dict[int, object] = {}
        self._holding = 0
        self._taken: int | None = None
        self._lost = False  # the taken signal's Interrupted was swallowed: it is sent again
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._old[signum] = signal.signal(signum, self._handle)
            self._old_hook, sys.unraisablehook = sys.unraisablehook, self._unraisable
        return self

    def __exit__(self, *exc) -> None:
        self._lost = False
        for signum, handler in self._old.items():
            signal.signal(signum, handler)
        if self._old:
            sys.unraisablehook = self._old_hook

    def _handle(self, signum, frame) -> None:
        if self._taken is not None and not self._lost:
            return
        self._taken = self._taken or signum
        self._lost = False
        if not self._holding:
            raise Interrupted(self._taken)

    def _unraisable(self, unraisable) -> None:
        """Where Python drops exceptions (a gc callback, as JAX's that runs at every
        collection, often while it compiles; a weakref finalizer; `__del__`) the handler's
        `Interrupted` would be printed and lost, and the run would stop only after its next
        written chunk. It is not printed; the signal is sent again 10 ms later, once that
        code has returned (or again, should it land in such code once more)."""
        if not (isinstance(unraisable.exc_value, Interrupted) and self._taken is not None):
            self._old_hook(unraisable)
            return
        self._lost = True
        threading.Timer(0.01, self._send_again).start()

    def _send_again(self) -> None:
        if not self._lost:  # raised meanwhile, or the block was left
            return
        if hasattr(signal, "pthread_kill"):  # a real signal also ends a blocking call (sleep)
            signal.pthread_kill(threading.main_thread().ident, self._taken)
        else:  # Windows
            _thread.interrupt_main(self._taken)

    @contextmanager
    def held(self) -> Iterator[None]:
        """A block no signal interrupts; a signal that came during it is raised after."""
        self._holding += 1
        try:
            yield
        finally:
            self._holding -= 1
        if self._taken is not None and not self._holding:
            self._lost = False
            raise Interrupted(self._taken)


def tree_hash(tree) -> str:
    """16 hex digits naming a pytree's arrays (each as float32 where floating, so that the
    name does not depend on JAX's precision setting) and its structure: a body's dimensions,
    a start pose, a list of constraints."""
    import equinox as eqx
    import jax
    import numpy as np

    arrays, rest = eqx.partition(tree, eqx.is_array)
    digest = hashlib.sha256(str(jax.tree.structure(rest)).encode())
    for leaf in jax.tree.leaves(arrays):
        a = np.asarray(leaf)
        a = a.astype(np.float32) if np.issubdtype(a.dtype, np.floating) else a
        digest.update(f"{a.dtype}{a.shape}".encode())
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()[:16]


def fsync_file(path: str) -> None:
    """Flush a written file's data to the disk."""
    with open(path, "rb+") as f:
        os.fsync(f.fileno())


def replace_atomically(path: str, text: str) -> None:
    """Write `text` to `path` through a temporary file beside it: the file is either the old
    one or the whole new one, never a part."""
    tmp = f"{path}.partial"
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def append_lines(path: str, text: str) -> None:
    """Append whole lines with one write, then flush and fsync, so that what follows a
    crash is every earlier chunk and at most one partial last line."""
    with open(path, "a", newline="", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def header_text(fields: list[tuple[str, str]], columns: list[str]) -> str:
    """The header of a results file: one ``# key: value`` line per field, then the column
    names."""
    for key, value in fields:
        if ":" in key or "\n" in key + value:
            raise ValueError(f"header field {key!r}: {value!r} cannot be written on one line")
    return "".join(f"# {k}: {v}\n" for k, v in fields) + ",".join(columns) + "\n"


@dataclass(frozen=True)
class Results:
    """A results file read back by `read_results`.

    `fields`: the header's ``# key: value`` pairs. `columns`: the column names. `ends`:
    the byte offset just past each whole row (`ends[i]` ends row i); `start`: the offset
    of the first row. `first_cells`: each whole row's first cell.
    """

    path: str
    fields: dict[str, str]
    columns: list[str]
    start: int
    ends: list[int]
    first_cells: list[str]


def read_results(path: str) -> Results:
    """The header and the whole rows of a results file (a final line without its newline,
    left by a killed process, is not a row). Errors name the file and the line."""
    fields: dict[str, str] = {}
    columns: list[str] | None = None
    ends: list[int] = []
    first: list[str] = []
    at = start = 0
    with open(path, "rb") as f:
        for number, raw in enumerate(f, start=1):
            at += len(raw)
            if not raw.endswith(b"\n"):
                break  # a partial last line
            try:
                line = raw.decode("utf-8").rstrip("\r\n")
            except UnicodeDecodeError:
                raise ValueError(f"{path}: line {number}: not UTF-8 text") from None
            if columns is None:
                if line.startswith("#"):
                    key, sep, value = line[1:].partition(":")
                    if not sep:
                        raise ValueError(f"{path}: line {number}: header line without 'key:'")
                    fields[key.strip()] = value.strip()
                    continue
                columns, start = line.split(","), at
                continue
            ends.append(at)
            first.append(line.split(",", 1)[0])
    if columns is None:
        raise ValueError(f"{path}: no column names after the header lines")
    return Results(path, fields, columns, start, ends, first)


def read_rows(results: Results) -> tuple[bytes, list[tuple[str, list[str]]]]:
    """The header of a results file read back (`read_results`), up to its first row, and its
    whole rows, each as (its line, its cells)."""
    with open(results.path, "rb") as f:
        data = f.read(results.ends[-1] if results.ends else results.start)
    lines = data[results.start :].decode().splitlines(True)
    return data[: results.start], list(zip(lines, csv.reader(lines)))


def truncate(path: str, size: int) -> None:
    """Cut a file to `size` bytes, on the disk."""
    with open(path, "rb+") as f:
        f.truncate(size)
        f.flush()
        os.fsync(f.fileno())
