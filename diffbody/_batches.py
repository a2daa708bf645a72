"""The one batch loop (docs/design.md, section 3): rows through one compiled function in
chunks of a fixed size, each chunk padded to that size with copies of its last row (so
every chunk reuses one compiled program and memory stays bounded by one chunk), its rows
sharded over the local devices when there are several, with a progress bar on stderr.
Reach, the sphere fit, motion capture and scaling all go through `map_chunks`.
"""

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ._progress import Progress


def chunk_rows(chunk_size: int, total: int, n_devices: int = 1) -> int:
    """Rows per compiled call: `chunk_size`, at most `total`, at least one, rounded up to a
    multiple of the device count."""
    chunk = max(1, min(int(chunk_size), int(total)))
    return -(-chunk // n_devices) * n_devices


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
):
    """`fn` over the rows of `arrays` (a tuple of pytrees, each leaf with the same leading
    axis) in chunks of `chunk` rows; the results as host (NumPy) arrays, padding dropped.

    With `carry` (not None), `fn(carry, *part) -> (carry, out)` runs the chunks in order,
    each from its predecessor's carry (frames of a recording), and the final carry is
    returned with the results. Else `fn(*part) -> out`.
    """
    total = len(jax.tree.leaves(arrays)[0])
    bar = Progress(total, progress, label, unit)
    parts = []
    for at in range(0, total, chunk):
        m = min(chunk, total - at)
        part = _pad(jax.tree.map(lambda a: np.asarray(a[at : at + m]), arrays), m, chunk)
        part = jax.tree.map(jnp.asarray, part)
        if sharding is not None:
            part = jax.device_put(part, sharding)
        if carry is None:
            out = fn(*part)
        else:
            carry, out = fn(carry, *part)
        parts.append(jax.tree.map(lambda a, m=m: np.asarray(a)[:m], out))
        bar.update(at + m)
    if not parts:
        raise ValueError("map_chunks: no rows")
    out = jax.tree.map(lambda *a: np.concatenate(a), *parts)
    return out if carry is None else (carry, out)
