"""Where a sphere-cloud fit without correspondences starts (docs/design.md, section 7).

The annealed fit (`_cloud_fit`) lands when every limb starts within about 15 cm of its
place; a person turned the other way, or an arm raised half a metre from the standard
position, is outside that basin. `search_start` finds a start inside it by a discrete search
that needs no solve: every candidate costs one walk and one robust chamfer distance.

1. Heading: the standard position turned about the vertical (through the root) by each of
   `YAWS` angles and moved onto the cloud by the median offset. Every heading goes on: a
   body seen from the front or from behind fills the cloud almost alike until its limbs
   are placed, and the search's cost cannot yet tell which heading the fit lands from.
2. Posture: from each heading, coordinate search over `GROUPS` (the whole body's placement,
   the spine, the proximal limb segments), each group's free components on a 3^k grid
   about the current values, the best grid point kept; the grid's step halves each round
   (`STEPS`) and the cost's scale narrows (`SCALES`: a wide scale first, so that a limb
   half a metre from its place already sees the cloud it should cover). The free vector's
   posture components are the reach core's bounded maps (section 6), so one step is alike
   for every joint.
3. The candidates, one per heading, in order of cost: the fit (`_cloud_fit`) anneals the
   best few side by side and keeps the one that explains the cloud best.

The cost (`chamfer_cost`) is the robust, symmetric chamfer distance in (centre, radius)
space: each model sphere to its nearest measured one and each measured sphere to its
nearest model one, each through Geman-McClure at scale `SCALE`, so outliers and far limbs
count at most 1 each. It needs no assignment, and a limb lying on the wrong part of the cloud
still pays for the part it left unexplained.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._body import Body
from ._cloud_residuals import Cloud, FitLayout, Start, model_spheres, pack

YAWS = 8  # headings tried: every 45 degrees (the root group turns by +-0.3 rad)
# Free-vector step of each round (bounded-map units; metres x 0.4 for the root's shift,
# rad x 0.5 for its heading): three rounds refine to within a quarter of the last step.
STEPS = (0.6, 0.3, 0.15)
# m: the chamfer cost's Geman-McClure scale in each round. At 0.06 m throughout, a limb
# the grid put 20 cm from its place scored as badly as one a metre off, and the search kept
# the limb where it was: 8 of 32 clouds (spread 0.3, any heading) had every wrist and ankle
# within 15 cm of its place, against 13 with the wide first round.
SCALES = (0.15, 0.08, 0.06)
# Groups searched in each round, in this order (the root's shift and heading first, then
# from the spine outward): (segment name or "spine" or "root", which free components).
GROUPS = (
    (("root", "shift_x"), ("root", "shift_y"), ("root", "shift_z"), ("root", "yaw")),
    (("spine", "flexion"), ("spine", "bending"), ("spine", "twist")),
    *(
        (
            (f"{side}_thigh", "swing_x"),
            (f"{side}_thigh", "swing_y"),
            (f"{side}_thigh", "twist"),
            (f"{side}_shank", "swing_y"),
        )
        for side in ("left", "right")
    ),
    *(
        (
            (f"{side}_upper_arm", "swing_x"),
            (f"{side}_upper_arm", "swing_y"),
            (f"{side}_upper_arm", "twist"),
            (f"{side}_forearm", "swing_y"),
        )
        for side in ("left", "right")
    ),
)
GRID = 81  # grid points per group: 3^4
# The root's free components per grid step, beside the posture's 1 (bounded-map units).
ROOT_UNIT = {"shift_x": 0.4, "shift_y": 0.4, "shift_z": 0.4, "yaw": 0.5}


def group_table(body: Body, lay: FitLayout) -> tuple[np.ndarray, np.ndarray]:
    """Per group, the free-vector index of each searched component (n_group, 4; padded with
    the first, whose padded offsets are 0) and the grid of offsets per step (n_group, 81,
    4), the current values (all zeros) first."""
    pose = lay.pose
    n_sx, n_sy, n_tw, n_sp, _ = pose.sizes
    slot = dict(zip(pose.chain.segments, range(len(pose.chain.segments))))
    first = {"swing_x": 0, "swing_y": n_sx, "twist": n_sx + n_sy}
    members = {"swing_x": pose.swing_x, "swing_y": pose.swing_y, "twist": pose.twist}
    spine0 = n_sx + n_sy + n_tw
    root0 = spine0 + n_sp
    index, grid = [], []
    for group in GROUPS:
        cols, unit = [], []
        for name, part in group:
            if name == "root":
                cols.append(root0 + {"shift_x": 0, "shift_y": 1, "shift_z": 2, "yaw": 5}[part])
                unit.append(ROOT_UNIT[part])
            elif name == "spine":
                if n_sp:
                    cols.append(spine0 + ("flexion", "bending", "twist").index(part))
                    unit.append(1.0)
            else:
                s = slot[body.segment_index(name)]
                cols.append(first[part] + members[part].index(s))
                unit.append(1.0)
        if not cols:
            continue
        points = sorted(
            itertools.product((-1, 0, 1), repeat=len(cols)), key=lambda p: sum(map(abs, p))
        )
        offsets = np.zeros((GRID, 4))
        offsets[: len(points), : len(cols)] = np.asarray(points) * unit
        index.append(cols + [cols[0]] * (4 - len(cols)))
        grid.append(offsets)
    return np.asarray(index), np.asarray(grid)


def squared_distances_fast(a: Float[Array, "n 4"], b: Float[Array, "m 4"]) -> Array:
    """(n, m) m^2 by one matrix product (the search only ranks candidates: float32's
    cancellation near zero, ~1e-7 m^2, is far below `SCALE`)."""
    d2 = jnp.sum(a * a, -1)[:, None] + jnp.sum(b * b, -1)[None] - 2 * a @ b.T
    return jnp.maximum(d2, 0.0)


def search_spheres(body: Body) -> np.ndarray:
    """The model spheres the search compares: per segment, ceil(count / 8) of its spheres
    (at most 3) spread along it, about 60 of the 400 (the cost's time goes with the number
    of pairs; a limb is placed as well by three spheres as by thirteen)."""
    seg = np.asarray(body.sphere_segment)
    z = np.asarray(body.sphere_origins)[:, 2]
    keep = []
    for s in np.unique(seg):
        own = np.flatnonzero(seg == s)
        own = own[np.argsort(z[own])]
        k = min(3, -(-len(own) // 8))
        keep += list(own[np.linspace(0, len(own) - 1, k).round().astype(int)])
    return np.asarray(sorted(keep))


def chamfer_cost(model: Float[Array, "n 4"], measured: Float[Array, "m 4"], scale) -> Array:
    """The robust symmetric chamfer distance (module docstring) at `scale` (m): mean
    Geman-McClure cost of each model sphere's nearest measured sphere plus that of each
    measured sphere's nearest model sphere, each in [0, 1]."""
    d2 = squared_distances_fast(model, measured)
    rho = lambda s: s / (s + scale**2)  # noqa: E731
    return jnp.mean(rho(jnp.min(d2, 1))) + jnp.mean(rho(jnp.min(d2, 0)))


def search_tables(body: Body, lay: FitLayout) -> tuple:
    """What `search_start` needs of the body, as nested tuples (static under jit): the
    groups' indices and grids (`group_table`) and the compared spheres (`search_spheres`)."""
    index, grid = group_table(body, lay)
    grid = tuple(tuple(map(tuple, g)) for g in grid.tolist())
    return tuple(map(tuple, index.tolist())), grid, tuple(search_spheres(body).tolist())


def search_start(start: Start, lay: FitLayout, cloud: Cloud, tables: tuple) -> tuple[Array, Array]:
    """The candidate starts' free vectors (YAWS, n_free), one per heading, and their costs
    (YAWS,), best first (module docstring), for the fit whose standard-position start is
    `start`. tables: `search_tables`."""
    index, grid, keep = (np.asarray(t) for t in tables)
    measured = cloud.measured
    x0 = start.x
    n_sx, n_sy, n_tw, n_sp, _ = lay.pose.sizes
    root0 = n_sx + n_sy + n_tw + n_sp

    def model_at(x):
        z = pack(lay, Start(start.problem, x, start.log_axial, start.log_radial))
        return model_spheres(start, lay, z)

    # 1. Headings: the standard position turned about the root and moved onto the cloud.
    rest = model_at(x0)
    p0 = start.problem.position0
    yaw = jnp.arange(YAWS, dtype=x0.dtype) * (2 * jnp.pi / YAWS)
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    zero, one = jnp.zeros_like(c), jnp.ones_like(c)
    Rz = jnp.stack([c, -s, zero, s, c, zero, zero, zero, one], -1).reshape(-1, 3, 3)
    turned = jnp.einsum("kij,nj->kni", Rz, rest[:, :3] - p0) + p0
    shift = jnp.median(measured[:, :3], 0) - jnp.median(turned, 1)
    xs = jnp.broadcast_to(x0, (YAWS,) + x0.shape)
    xs = xs.at[:, root0 : root0 + 3].add(shift).at[:, root0 + 5].add(yaw)

    # 2. Posture: coordinate search over the groups, the step halving each round.
    def improve(xs, xs_g):
        # Every heading's candidates in one vmap (a vmap nested in a vmap here trips XLA's
        # dot simplifier).
        cols, offsets, scale = xs_g
        n = xs.shape[0]
        candidates = jnp.broadcast_to(xs[:, None], (n,) + offsets.shape[:1] + x0.shape)
        candidates = candidates.at[:, :, cols].add(offsets[None])
        flat = candidates.reshape(-1, x0.shape[0])
        cost = jax.vmap(lambda xc: chamfer_cost(model_at(xc)[keep], measured, scale))(flat)
        cost = cost.reshape(n, -1)
        k = jnp.argmin(cost, axis=1)
        pick = jnp.arange(n)
        return candidates[pick, k], cost[pick, k]

    rounds = len(STEPS)
    idx = np.tile(index, (rounds, 1))
    offs = np.tile(grid, (rounds, 1, 1)) * np.repeat(STEPS, len(index))[:, None, None]
    scales = np.repeat(SCALES, len(index))
    xs, cost = jax.lax.scan(
        improve, xs, (jnp.asarray(idx), jnp.asarray(offs, x0.dtype), jnp.asarray(scales, x0.dtype))
    )
    order = jnp.argsort(cost[-1])
    return xs[order], cost[-1, order]
