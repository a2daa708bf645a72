"""Signed distances between the body's spheres and to the environment (docs/design.md,
section 10): pure, differentiable JAX; one row per pair of segments (or segment and shape),
the closest of its sphere pairs.

The closest pair of a group is found without derivatives among all of its sphere pairs, and
only that pair is measured again with derivatives: a row's gradient is its closest pair's
(exact wherever the closest pair is unique), and a Jacobian costs a few hundred pairs, not
tens of thousands."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._rotations import safe_norm
from ._environment import Environment, sphere_environment_distances


def sphere_distances(
    centers: Float[Array, "n 3"],
    radii: Float[Array, " n"],
    i: Int[Array, " P"],
    j: Int[Array, " P"],
) -> Float[Array, " P"]:
    """Signed distances (m) of sphere pairs (i, j): |c_i - c_j| - r_i - r_j."""
    return safe_norm(centers[i] - centers[j]) - radii[i] - radii[j]


def _closest(values: Array, group: np.ndarray, n_groups: int) -> Array:
    """Per group, the index of its smallest value (the first on ties); (n_groups,)."""
    low = jax.ops.segment_min(values, group, n_groups, indices_are_sorted=False)
    index = jnp.arange(values.shape[0])
    hit = jnp.where(values <= low[group], index, values.shape[0])
    return jnp.minimum(jax.ops.segment_min(hit, group, n_groups), values.shape[0] - 1)


def closest_pair_gaps(
    centers: Float[Array, "n 3"],
    radii: Float[Array, " n"],
    i: Int[Array, " P"],
    j: Int[Array, " P"],
    allowance: Float[Array, " P"],
    group: np.ndarray,
    n_groups: int,
) -> tuple[Float[Array, " S"], Int[Array, " S"]]:
    """Per group of sphere pairs (a pair of segments), the smallest signed distance less
    the pair's allowance (m, its rest overlap), and which pair it is. Differentiable in the
    centres and radii through the closest pair."""
    fixed = jax.lax.stop_gradient((centers, radii))
    gap = sphere_distances(*fixed, i, j) - allowance
    k = _closest(gap, group, n_groups)
    return sphere_distances(centers, radii, i[k], j[k]) - allowance[k], k


def environment_gaps(
    centers: Float[Array, "n 3"],
    radii: Float[Array, " n"],
    env: Environment,
    segment: np.ndarray,
    n_segments: int,
) -> tuple[Float[Array, "n_seg n_shape"], Int[Array, "n_seg n_shape"]]:
    """Per segment and shape, the smallest signed distance (m) of the segment's spheres
    (`segment`: each sphere's row) to the shape, and which sphere it is."""
    if env.n_shapes == 0:
        return jnp.zeros((n_segments, 0), centers.dtype), jnp.zeros((n_segments, 0), int)
    fixed = jax.lax.stop_gradient((centers, radii))
    d = sphere_environment_distances(*fixed, env)  # (n, n_shape)
    k = jax.vmap(lambda col: _closest(col, segment, n_segments), in_axes=1, out_axes=1)(d)
    # Column s's closest spheres measured again, with derivatives, against shape s alone.
    rows = jax.vmap(lambda kk: sphere_environment_distances(centers[kk], radii[kk], env))(k.T)
    return jnp.diagonal(rows, axis1=0, axis2=2), k
