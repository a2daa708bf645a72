"""The one batch loop (docs/design.md, section 3): rows through one compiled function in
chunks of a fixed size, each chunk padded to that size with copies of its last row (so
every chunk reuses one compiled program and memory stays bounded by one chunk), its rows
sharded over the local devices when there are several, with a progress bar on stderr.
Reach, the sphere fit, motion capture and scaling all go through `map_chunks`.
"""

import contextlib
from collections.abc import Callable, Sequence

import jax
import numpy as np

from .._progress import Progress
from ._chunk_store import ChunkStore
from ._streaming import Interrupted, Interrupts


def bucket(n: int, least: int = 1) -> int:
    """The rows of the bucket that holds n rows: `least`, then doubling."""
    rows = least
    while rows < n:
        rows *= 2
    return rows


def chunk_rows(chunk_size: int, total: int, n_devices: int = 1) -> int:
    """Rows per compiled call: `chunk_size`, at most `total`, at least one, rounded up to a
    multiple of the device count."""
    chunk = max(1, min(int(chunk_size), int(total)))
    return -(-chunk // n_devices) * n_devices


def take_rows(tree, rows):
    """The given rows of every array of the tree."""
    return jax.tree.map(lambda a: a[rows], tree)


def put_rows(tree, rows: np.ndarray, new):
    """A copy of `tree` (host arrays) with `rows` replaced by `new`'s."""

    def put(a, r):
        a = np.array(a, copy=True)
        a[rows] = r
        return a

    return jax.tree.map(put, tree, new)


def row_sharding(devices: Sequence[jax.Device] | None = None) -> jax.sharding.Sharding:
    """Where a chunk's rows go: split over `devices` (default: the local ones) along the
    leading axis when there are several, else on the one device."""
    devices = list(jax.local_devices() if devices is None else devices)
    if len(devices) > 1:
        mesh = jax.sharding.Mesh(np.asarray(devices), ("batch",))
        return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    return jax.sharding.SingleDeviceSharding(devices[0])


def _pad(tree, m: int, chunk: int):
    """The rows of a part, padded to `chunk` with copies of its last row."""
    if m == chunk:
        return tree
    return jax.tree.map(lambda a: np.concatenate([a, np.repeat(a[-1:], chunk - m, 0)]), tree)


def map_chunks(
    fn: Callable,
    arrays,
    *,
    chunk: int,
    sharding: jax.sharding.Sharding | None = None,
    progress: bool = False,
    label: str = "batch",
    unit: str = "row",
    carry=None,
    store: ChunkStore | None = None,
):
    """`fn` over the rows of `arrays` (a tuple of pytrees, each leaf with the same leading
    axis) in chunks of `chunk` rows; the results as host (NumPy) arrays, padding dropped.

    With `carry` (not None), `fn(carry, *part) -> (carry, out)` runs the chunks in order,
    each from its predecessor's carry (frames of a recording), and the final carry is
    returned with the results. Else `fn(*part) -> out`.

    With `store` (not with `carry`), each finished chunk's outputs are kept in its folder and
    the chunks it holds already are read, not solved; SIGINT / SIGTERM between or inside
    chunks raise `Interrupted` saying how many rows the folder holds.
    """
    if store is not None and carry is not None:
        raise ValueError("map_chunks: a store keeps independent chunks, not a carry")
    total = len(jax.tree.leaves(arrays)[0])
    bar = Progress(total, progress, label, unit)
    parts, treedef, done = [], None, 0
    with Interrupts() if store is not None else contextlib.nullcontext() as signals:
        try:
            for index, at in enumerate(range(0, total, chunk)):
                m = min(chunk, total - at)
                part = _pad(jax.tree.map(lambda a: np.asarray(a[at : at + m]), arrays), m, chunk)
                part = jax.device_put(part)
                kept = store.load(index) if store is not None else None
                if kept is not None:
                    # The outputs' structure, traced once (not compiled) where no chunk ran.
                    treedef = treedef or jax.tree.structure(jax.eval_shape(fn, *part))
                    parts.append(jax.tree.unflatten(treedef, kept))
                    done = at + m
                    bar.update(done)
                    continue
                if sharding is not None:
                    part = jax.device_put(part, sharding)
                if carry is None:
                    out = fn(*part)
                else:
                    carry, out = fn(carry, *part)
                    # Uncommitted, as the first chunk's carry: a carry committed to its
                    # device would compile `fn` a second time from the second chunk on.
                    carry = jax.device_put(jax.tree.map(np.asarray, carry))
                out = jax.tree.map(lambda a, m=m: np.asarray(a)[:m], out)
                treedef = jax.tree.structure(out)
                if store is not None:
                    with signals.held():
                        store.save(index, jax.tree.leaves(out))
                parts.append(out)
                done = at + m
                bar.update(done)
        except KeyboardInterrupt as e:  # Interrupted, or a SIGINT seen inside a JAX call
            if store is None:
                raise
            signum = e.signum if isinstance(e, Interrupted) else 2
            raise Interrupted(signum, done, total, store.path) from None
    if not parts:
        raise ValueError("map_chunks: no rows")
    out = jax.tree.map(lambda *a: np.concatenate(a), *parts)
    return out if carry is None else (carry, out)
