"""Where a solve starts (docs/design.md, section 6): the closed-form limb start (or the
start pose) first, then fixed points spread over the free variables' range.

Start 0 is the phase's first start (`_limb_start` in the limbs' phase, else the start
pose), so a reachable target keeps the most natural posture. Start k > 0 is the k-th point
of a Halton sequence over the limbs' free variables (u in [-1.3, 1.3]; the trunk, the spine
target and the root's placement, kept at the start, so that the trunk never starts bent
further than the reach needs): low-discrepancy, so the first few starts already cover the
range evenly instead of clustering as independent random draws do, and the same for every
problem, so results are reproducible.
"""

import functools

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

SPREAD = 1.3  # the starts' range of the free variables (sin map: +-96 % of each range)


@functools.cache
def halton(n_starts: int, dim: int) -> np.ndarray:
    """(n_starts, dim) points of the Halton sequence in [-SPREAD, SPREAD] (row 0 unused).

    Unscrambled: dimension d is the radical inverse of the point's index in base the d-th
    prime (no two dimensions share a base), index 0 first: scipy.stats.qmc.Halton's table
    with scramble=False, without importing scipy.stats (about a second of a process's
    start). Scrambling would spread the large-prime
    dimensions of a whole-body problem better over the first 64 points, but it would move
    every start of the limb problems (9 to 20 variables) and with them the reaches that
    need a second start."""
    index = np.arange(n_starts)
    points = np.zeros((n_starts, max(dim, 1)))
    for d, base in enumerate(_primes(max(dim, 1))):
        i, f = index.copy(), 1.0
        while np.any(i > 0):
            f /= base
            points[:, d] += f * (i % base)
            i //= base
    return SPREAD * (2.0 * points[:, :dim] - 1.0)


def _primes(n: int) -> list[int]:
    """The first n primes."""
    primes: list[int] = []
    k = 2
    while len(primes) < n:
        if all(k % p for p in primes if p * p <= k):
            primes.append(k)
        k += 1
    return primes


MAX_STARTS = 64  # starts beyond this many repeat the table (each is tried at most once)


def nth_start(
    first: Float[Array, " n"],
    x0: Float[Array, " n"],
    k: Int[Array, ""],
    n_trunk: int,
    free: Bool[Array, " n"] | None = None,
) -> Float[Array, " n"]:
    """The free vector of start k (traced): `first` for k = 0, else the k-th Halton point
    (k modulo `MAX_STARTS`) with the trunk (the last `n_trunk` entries: spine target, root
    placement) kept at x0, the start pose's. `free` (data): only these entries move, the
    j-th of them along the Halton point's j-th dimension (as in a vector of those alone)."""
    n = x0.shape[0]
    if n == 0:
        return x0
    point = jnp.asarray(halton(MAX_STARTS, n), x0.dtype)[jnp.mod(k, MAX_STARTS)]
    kept = np.arange(n) >= n - n_trunk
    if free is not None:
        point = point[jnp.maximum(jnp.cumsum(free) - 1, 0)]
        kept = kept | ~free
    return jnp.where(k == 0, first, jnp.where(kept, x0, point))
