"""Host values onto the device without compiling (docs/design.md, section 9, "Host set-up").

In jax 0.10 `jnp.asarray` of a NumPy array compiles a small program per shape and dtype
("jit_stage"), and eager `jnp` operations on host data (`jnp.asarray(x, dtype)`, `jnp.zeros`,
`jnp.stack`) compile one each ("jit_convert_element_type", "jit_broadcast_in_dim", ...). Each
compiles in well under a second, so JAX's persistent cache never keeps them: every process
pays their tracing and compiling again. Built in NumPy and moved with `jax.device_put`, the
same arrays compile nothing.
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


def device_array(values, dtype=float) -> Array:
    """Host values (NumPy arrays, Python numbers, nested lists) as one device array of JAX's
    canonical `dtype`: `float` is JAX's default float type (float32, float64 under x64),
    `int` its default integer type, `bool` bool; as `jnp.asarray(values, dtype)` gives, with
    no program compiled. The values must be concrete (no tracers)."""
    return jax.device_put(np.asarray(values, dtype=jnp.result_type(dtype)))


def take(table: np.ndarray | Array, index) -> np.ndarray | np.generic | Array:
    """table[index] of a table: on the host for a host table and host indices (a constant
    in a traced program), a gather where either is data."""
    if isinstance(index, jax.Array) or isinstance(table, jax.Array):
        return jnp.asarray(table)[index]
    return np.asarray(table)[np.asarray(index, int)]
