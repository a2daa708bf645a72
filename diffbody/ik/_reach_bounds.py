"""How far a phase's chain reaches (host, docs/design.md, section 6): the bound a target
must lie within for the phase to reach it, read off the start's links (`host_links`,
`forward`'s one program per body; the standard position's remembered per body)."""

import equinox as eqx
import numpy as np
from jaxtyping import ArrayLike

from .._body import Body, Pose
from .._body_cache import BodyCache
from .._kinematics import Links, forward
from ..problem._constraints import GEOMETRY
from ..problem._unknowns import Layout, point_segment


def _own_extra(body: Body, index: int) -> float:
    """How far a feature effector can lie beyond its segment's distal joint (0 for a
    joint): its sphere's farthest point from the proximal joint, less the length."""
    n_j = body.n_joints
    if index < n_j:
        return 0.0
    sph = body.feature_sphere[index - n_j]
    origin, radius = (np.asarray(a)[sph] for a in (body.sphere_origins, body.sphere_radii))
    seg = body.sphere_segment[sph]
    return max(float(np.linalg.norm(origin) + radius) - float(np.asarray(body.lengths)[seg]), 0.0)


def reach_bound(body: Body, layout: Layout, links: Links) -> tuple[np.ndarray, np.ndarray]:
    """Per point target, the fixed point its chain hangs from (n_p, 3; start links, global
    order) and the farthest its effector can be from it (n_p,): the sum of the live
    segments' lengths on its path, the effector's own segment counted to the effector. inf
    where the root is free or the whole tree moves (no fixed point); standing, from the
    ankle of the first of `Body.feet` (the left), the leg counted too."""
    n_j = body.n_joints
    lengths = np.asarray(body.lengths)
    live = set(layout.chain.segments)
    anchor, bound = [], []
    for index in layout.points:
        seg = point_segment(body, index)
        path = [s for s in body.path_to_top(seg) if s in live]
        if layout.standing and not layout.full and path:
            # Standing, the chain hangs from a planted foot: from its ankle, up the leg.
            foot = body.feet[0]
            leg = list(body.path_to_top(foot)[1:])
            anchor.append(np.asarray(links.p_proximal[foot]))
            bound.append(sum(lengths[s] for s in set(path + leg)) + _own_extra(body, index))
            continue
        if layout.root or layout.full or not path:
            anchor.append(np.zeros(3))
            bound.append(np.inf if path else 0.0)
            continue
        top = path[-1]
        anchor.append(np.asarray(links.p_proximal[top]))
        own = lengths[seg]
        if index >= n_j:
            sph = body.feature_sphere[index - n_j]
            origin, radius = (np.asarray(a)[sph] for a in (body.sphere_origins, body.sphere_radii))
            own = float(np.linalg.norm(origin) + radius)
        bound.append(sum(lengths[s] for s in path if s != seg) + (own if seg in live else 0.0))
    return np.asarray(anchor).reshape(-1, 3), np.asarray(bound)


def host_links(body: Body, init: Pose) -> Links:
    """The start's links of every segment (global order) as NumPy arrays, read off
    `forward` (one compiled program per body, shared with the pictures and the set-up of
    the constraints): a segment's proximal joint is its parent's distal one."""
    k = forward(body, init)
    joints = np.asarray(k.joint_positions)
    # Filled in by tree_at, as NumPy arrays: Links' annotations name JAX arrays.
    links = Links(k.R_world_base, k.R_world_twisted, k.centroids, k.centroids)
    return eqx.tree_at(
        lambda li: (li.R_base, li.R_twisted, li.p_proximal, li.p_distal),
        links,
        (
            np.asarray(k.R_world_base),
            np.asarray(k.R_world_twisted),
            joints[np.asarray(body.parent) + 1],
            joints[1:],
        ),
    )


def rest_links(body: Body) -> Links:
    """`host_links` of the body's standard position, remembered per body (what `forward`
    of it reads): a default reach's first phase starts there on every call."""
    return _REST_LINKS.get(body, None, lambda: host_links(body, body.rest_pose()))


# What `forward` of the standard position reads: the socket turns and the pinned frame too.
STANDARD_POSITION = GEOMETRY + ("R_parent_socket", "R_world_pin_rest")
_REST_LINKS = BodyCache(STANDARD_POSITION, size=64)


def beyond_bound(body: Body, layout: Layout, init: Pose, xyz: ArrayLike, links=None) -> np.ndarray:
    """Whether point targets xyz (..., n_p, 3) lie beyond the phase's reach bound, the sum
    of its chain's lengths (host): what `ReachResult.beyond` reports. `links`: the start's
    (`host_links`), when already at hand."""
    links = host_links(body, init) if links is None else links
    anchor, bound = reach_bound(body, layout, links)
    return _farther(xyz, anchor, bound)


def out_of_reach(body: Body, layout: Layout, init: Pose, xyz: ArrayLike, links=None) -> np.ndarray:
    """Whether point targets xyz (..., n_p, 3) lie out of the phase's reach (host): farther
    from every place the top segment of their chain can put its distal joint than the rest
    of the chain is long. The top segment swings within its cone (the clavicle by 20
    degrees), so its distal joint stays on a cap of the sphere around its proximal joint;
    the rest is bounded by its lengths. A necessary condition for a reach, tighter than
    `beyond_bound` where the chain hangs from a segment of little swing."""
    links = host_links(body, init) if links is None else links
    anchor, bound = reach_bound(body, layout, links)
    lengths, swing_lo, swing_hi, swing_max, R_parent_socket, R_socket_rest = (
        np.asarray(a)
        for a in (
            body.lengths,
            body.swing_lo,
            body.swing_hi,
            body.swing_max,
            body.R_parent_socket,
            body.R_socket_rest,
        )
    )
    xyz = np.asarray(xyz, float)
    out = _farther(xyz, anchor, bound)
    live = set(layout.chain.segments)
    for j, index in enumerate(layout.points):
        seg = point_segment(body, index)
        path = [s for s in body.path_to_top(seg) if s in live]
        if layout.root or layout.full or len(path) < 2 or not np.isfinite(bound[j]):
            continue
        top = path[-1]
        length = float(lengths[top])
        lo, hi = np.abs(swing_lo[top]), np.abs(swing_hi[top])
        half = min(float(swing_max[top]), float(np.hypot(*np.maximum(lo, hi))), np.pi)
        R_socket = links.R_twisted[int(body.parent[top])] @ R_parent_socket[top]
        centre = R_socket @ R_socket_rest[top][:, 2]
        with np.errstate(invalid="ignore", over="ignore"):
            v = xyz[..., j, :] - anchor[j]
            D = np.linalg.norm(v, axis=-1)
            cos = np.clip(v @ centre / np.where(D > 0, D, 1.0), -1.0, 1.0)
            beta = np.arccos(cos)
            gap = np.where(
                beta <= half,
                np.abs(D - length),
                np.sqrt(np.maximum(D**2 + length**2 - 2 * D * length * np.cos(beta - half), 0)),
            )
            out[..., j] |= np.isfinite(D) & (gap > bound[j] - length)
    return out


def _farther(xyz: ArrayLike, anchor: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """Whether points xyz (..., n_p, 3) lie farther than `bound` (n_p,) from `anchor`."""
    xyz = np.asarray(xyz, float)
    with np.errstate(invalid="ignore", over="ignore"):
        # |xyz - anchor| scaled by its largest component, so 1e30 m does not overflow.
        d = xyz - anchor
        scale = np.max(np.abs(d), axis=-1)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        dist = scale * np.linalg.norm(d / scale[..., None], axis=-1)
        return np.isfinite(xyz).all(-1) & (dist > bound)
