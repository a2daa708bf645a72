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
from jaxtyping import Array, Float, Int

SPREAD = 1.3  # the starts' range of the free variables (sin map: +-96 % of each range)


@functools.cache
def halton(n_starts: int, dim: int) -> np.ndarray:
    """(n_starts, dim) points of the Halton sequence in [-SPREAD, SPREAD] (row 0 unused).

    scipy's unscrambled sequence: dimension d in base the d-th prime for any dim (no two
    dimensions share a base). Scrambling would spread the large-prime dimensions of a
    whole-body problem better over the first 64 points, but it would move every start of
    the limb problems (9 to 20 variables) and with them the reaches that need a second
    start: kept unscrambled, those are as before."""
    from scipy.stats import qmc  # on first use: importing scipy.stats costs a few tenths of a s

    points = qmc.Halton(d=max(dim, 1), scramble=False).random(n_starts)[:, :dim]
    return SPREAD * (2.0 * points - 1.0)


MAX_STARTS = 64  # starts beyond this many repeat the table (each is tried at most once)


def nth_start(
    first: Float[Array, " n"], x0: Float[Array, " n"], k: Int[Array, ""], n_trunk: int
) -> Float[Array, " n"]:
    """The free vector of start k (traced): `first` for k = 0, else the k-th Halton point
    (k modulo `MAX_STARTS`) with the trunk (the last `n_trunk` entries: spine target, root
    placement) kept at x0, the start pose's."""
    n = x0.shape[0]
    if n == 0:
        return x0
    table = jnp.asarray(halton(MAX_STARTS, n), x0.dtype)
    point = jnp.where(np.arange(n) >= n - n_trunk, x0, table[jnp.mod(k, MAX_STARTS)])
    return jnp.where(k == 0, first, point)
