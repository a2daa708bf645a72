"""Standing: the spheres a foot stands on, the support polygon they span on the floor, and
how far the centre of gravity's ground projection lies inside it (docs/design.md, section 10).
"""

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body, rest_geometry

# A foot's spheres whose lowest point lies within this of the foot's lowest in the standard
# position (feet flat) are the ones it stands on: the heel's and the ball's.
SOLE = 0.005  # m


def sole_spheres(body: Body, segments: Sequence[str]) -> np.ndarray:
    """Indices of the spheres the segments stand on in the standard position (feet flat):
    per segment, of those whose bottom lies within `SOLE` of its lowest, the corners of
    their contact points' convex hull (the others lie inside the support polygon and add
    nothing to it, nor to holding the foot in place)."""
    _, centers = rest_geometry(body)
    r = np.asarray(body.sphere_radii, float)
    out = []
    for name in segments:
        k = body.segment_spheres(name)
        if not k.size:
            raise ValueError(f"on_floor: segment {name!r} has no spheres to stand on")
        bottom = centers[k, 2] - r[k]
        sole = k[bottom <= bottom.min() + SOLE]
        out += sole[_hull_corners(centers[sole, :2])].tolist()
    return np.asarray(out, int)


def _hull_corners(xy: np.ndarray) -> np.ndarray:
    """Indices of the corners of the convex hull of points xy (k, 2) (monotone chain),
    all of them when there are fewer than three or they lie on a line."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    if len(xy) < 3:
        return order

    def half(idx):
        chain: list[int] = []
        for i in idx:
            while len(chain) >= 2:
                a, b = xy[chain[-2]], xy[chain[-1]]
                cross = (b[0] - a[0]) * (xy[i][1] - a[1]) - (b[1] - a[1]) * (xy[i][0] - a[0])
                if cross > 1e-12:
                    break
                chain.pop()
            chain.append(int(i))
        return chain

    corners = half(order)[:-1] + half(order[::-1])[:-1]
    return np.asarray(sorted(set(corners)) if len(corners) >= 3 else order, int)


def support_edges(
    xy: Float[Array | np.ndarray, "k 2"],
) -> tuple[Array | np.ndarray, Array | np.ndarray, Array | np.ndarray]:
    """The support polygon of contact points xy (k >= 1) as half-planes n . p <= h over
    every ordered pair of points (k^2 candidates): unit outward normals (k^2, 2), offsets
    (k^2,) and which are edges of the convex hull (k^2,). An edge is a pair with every point
    on or inside its line; traceable (no host hull). A single point or a line's hull is
    degenerate: its edges pass through it, and the inside distance is <= 0. A NumPy xy is
    worked in NumPy (host set-up: no program compiled), anything else in JAX."""
    xp = np if isinstance(xy, np.ndarray) else jnp
    k = xy.shape[0]
    a = xp.repeat(xy, k, axis=0)
    b = xp.tile(xy, (k, 1))
    t = b - a
    n = xp.stack([t[:, 1], -t[:, 0]], axis=-1)  # right of a -> b: outward for a CCW hull
    length = xp.sqrt(xp.sum(n * n, -1))
    ok = length > 1e-9
    n = n / xp.where(ok, length, 1.0)[:, None]
    h = xp.sum(n * a, -1)
    side = xy @ n.T - h[None]  # (k, k^2)
    edge = ok & xp.all(side <= 1e-9, axis=0)
    return n, h, edge


def inside_distance(p: Float[Array, "2"], normals, offsets, edge) -> Array:
    """How far p lies inside the polygon (m): the smallest distance to an edge's line,
    negative outside."""
    d = offsets - normals @ p
    return jnp.min(jnp.where(edge, d, jnp.inf))
