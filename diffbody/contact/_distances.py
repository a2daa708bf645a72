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


def _closest(
    values: Array, group: Int[Array | np.ndarray, " m"], n_groups: int
) -> tuple[Array, Array]:
    """Per group, the index of its smallest value (the first on ties) and whether the group
    has any value; (n_groups,) each. An empty group's index is a valid one (the last)."""
    low = jax.ops.segment_min(values, group, n_groups, indices_are_sorted=False)
    index = jnp.arange(values.shape[0])
    hit = jnp.where(values <= low[group], index, values.shape[0])
    first = jax.ops.segment_min(hit, group, n_groups)
    return jnp.minimum(first, values.shape[0] - 1), first < values.shape[0]


def closest_pair_gaps(
    centers: Float[Array, "n 3"],
    radii: Float[Array, " n"],
    i: Int[Array, " P"],
    j: Int[Array, " P"],
    allowance: Float[Array, " P"],
    group: Int[Array | np.ndarray, " P"],
    n_groups: int,
) -> tuple[Float[Array, " S"], Int[Array, " S"]]:
    """Per group of sphere pairs (a pair of segments), the smallest signed distance less
    the pair's allowance (m, its rest overlap), and which pair it is. Differentiable in the
    centres and radii through the closest pair."""
    fixed = jax.lax.stop_gradient((centers, radii))
    gap = sphere_distances(*fixed, i, j) - allowance
    k, _ = _closest(gap, group, n_groups)
    return sphere_distances(centers, radii, i[k], j[k]) - allowance[k], k


def environment_gaps(
    centers: Float[Array, "n 3"],
    radii: Float[Array, " n"],
    env: Environment,
    segment: Int[Array | np.ndarray, " n"],
    n_segments: int,
) -> tuple[Float[Array, "n_seg n_shape"], Int[Array, "n_seg n_shape"]]:
    """Per segment and shape, the smallest signed distance (m) of the segment's spheres
    (`segment`: each sphere's row) to the shape, and which sphere it is. A row without
    spheres (the whole body's) is +inf, its sphere index meaningless."""
    if env.n_shapes == 0:
        return jnp.zeros((n_segments, 0), centers.dtype), jnp.zeros((n_segments, 0), int)
    fixed = jax.lax.stop_gradient((centers, radii))
    d = sphere_environment_distances(*fixed, env)  # (n, n_shape)
    k, present = jax.vmap(lambda col: _closest(col, segment, n_segments), in_axes=1, out_axes=1)(d)
    # Column s's closest spheres measured again, with derivatives, against shape s alone.
    rows = jax.vmap(lambda kk: sphere_environment_distances(centers[kk], radii[kk], env))(k.T)
    return jnp.where(present, jnp.diagonal(rows, axis1=0, axis2=2), jnp.inf), k
