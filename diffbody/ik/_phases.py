"""The phases of a reach solve and the drivers that try their starts (docs/design.md,
section 6).

A solve runs in phases, as a person reaches: first the limbs (every unknown below the
trunk: clavicle, arm, hand; thigh, shank, foot; the head on the neck), with the spine, the
pelvis and the whole body held as in `init`; only if that misses, the trunk joins (the
spine as its Bendspine target, the root's placement when free), starting from the limbs'
closest reach. Within a phase, starts are tried in turn (`init` first, then the fixed
points of `_starts`) until every target is reached, unless the target lies beyond the
phase's reach bound (the sum of its chain's lengths), which decides up front that no start
can reach it. With concrete inputs the host drives phases and starts (`solve_host`), so only
what a target needs is compiled or run; under a JAX transformation (`solve_traced`) the
starts run side by side and the kept attempt is selected with `jnp.where`.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._body import Body, Pose
from .._spine import spine_angles
from ._attempt import assess, attempt, better, no_gradient, solve_free
from ._problem import reach_bound, start_links
from ._targets import TargetSet
from ._unknowns import Layout, make_layout, path_to_top


def is_none(x) -> bool:
    """Whether x is None: the `is_leaf` that lets `eqx.tree_at` fill an empty field."""
    return x is None


def is_traced(*trees) -> bool:
    """Whether any leaf of the trees is a JAX tracer (under jit, grad, vmap)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees))


# --- the phases -------------------------------------------------------------------------
def trunk_segments(body: Body) -> set[int]:
    """The whole body, the spine's segments and everything above them (the pelvis)."""
    trunk = {0}
    if body.spine is not None:
        for name in body.spine.segment_names:
            trunk |= set(path_to_top(body, body.segment_index(name)))
    return trunk


def phase_layouts(
    body: Body,
    ts: TargetSet,
    *,
    spine: bool,
    free_root: bool,
    segments: Sequence[str] | None,
) -> list[Layout]:
    """The layouts of the phases: the limbs alone, then everything (one layout when the two
    coincide or the limbs have no unknown on a target's chain). Cached per body structure
    and limits (host work of milliseconds, on every call otherwise)."""
    ranges = (body.swing_lo, body.swing_hi, body.twist_lo, body.twist_hi)
    if is_traced(ranges):
        return _phase_layouts(body, ts, spine, free_root, segments)
    key = (
        jax.tree.structure(body),
        tuple(np.asarray(a).tobytes() for a in ranges),
        ts.point_index,
        ts.axis_segment,
        spine,
        free_root,
        None if segments is None else tuple(segments),
    )
    if key not in _LAYOUTS:
        _LAYOUTS[key] = _phase_layouts(body, ts, spine, free_root, segments)
    return _LAYOUTS[key]


_LAYOUTS: dict = {}


def _phase_layouts(body, ts, spine, free_root, segments) -> list[Layout]:
    """`phase_layouts`, uncached."""
    points, axes = ts.point_index, ts.axis_segment
    movable = set(range(body.n_segments))
    if segments is not None:
        movable = {body.segment_index(name) for name in segments}
    full = make_layout(body, points, axes, movable, spine, free_root)
    limbs = make_layout(body, points, axes, movable - trunk_segments(body), False, False)
    if limbs.n_free == 0 or limbs.n_free == full.n_free:
        return [full]
    return [limbs, full]


def beyond_bound(body: Body, layout: Layout, init: Pose, xyz: ArrayLike) -> np.ndarray:
    """Whether point targets xyz (..., n_p, 3) lie beyond the phase's reach bound (host)."""
    links = jax.tree.map(np.asarray, _start_links_jit(body, init)[0])
    anchor, bound = reach_bound(body, layout, links)
    xyz = np.asarray(xyz, float)
    with np.errstate(invalid="ignore", over="ignore"):
        # |xyz - anchor| scaled by its largest component, so 1e30 m does not overflow.
        d = xyz - anchor
        scale = np.max(np.abs(d), axis=-1)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        dist = scale * np.linalg.norm(d / scale[..., None], axis=-1)
        return np.isfinite(xyz).all(-1) & (dist > bound)


_start_links_jit = eqx.filter_jit(start_links)


# --- the drivers ------------------------------------------------------------------------
def _all_starts(body, layout, init, targets, starts: int, max_steps: int, tol_p, tol_a):
    """Every start side by side: the free vector of the first that reaches (else of the
    closest) and the steps of all."""

    def one(k):
        x, steps = solve_free(body, layout, init, targets, k, max_steps, tol_p, tol_a)
        return x, assess(body, layout, init, targets, x, steps, tol_p, tol_a)

    xs, tries = jax.vmap(one)(jnp.arange(starts))
    k = jnp.where(jnp.any(tries.ok), jnp.argmax(tries.ok), jnp.argmin(tries.cost))
    return xs[k], jnp.sum(tries.steps)


# Compiled once per problem shape and reused by every later call (under jax.grad too: their
# inputs carry no derivatives, so the compiled solve is the same).
_all_starts_jit = eqx.filter_jit(_all_starts)
_assess_jit = eqx.filter_jit(assess)
_attempt_jit = eqx.filter_jit(attempt)


def _select(take: Array, a, b):
    """a where `take`, else b, leaf by leaf."""
    return jax.tree.map(lambda x, y: jnp.where(take, x, y), a, b)


def solve_host(body, layouts, init, ts, starts, max_steps, tols):
    """Phases and starts driven from the host: each attempt runs only if needed. Returns
    the kept `Attempt`, the solver steps over all attempts, and per point target whether it
    lies beyond the reach bound of the last phase tried."""
    best, steps = None, 0
    beyond_final = np.zeros(ts.point_xyz.shape[0], bool)
    start_pose = init
    for layout in layouts:
        beyond = beyond_bound(body, layout, start_pose, ts.point_xyz)
        beyond_final = beyond
        for k in range(starts if not beyond.any() else 1):
            a = _attempt_jit(body, layout, start_pose, ts, jnp.asarray(k), max_steps, *tols)
            steps += int(a.steps)
            if best is None or bool(better(a, best)):
                best = a
            if bool(a.ok):
                return best, steps, beyond
        start_pose = best.pose  # the trunk joins from the limbs' closest reach
    return best, steps, beyond_final


def solve_traced(body, layouts, init, ts, starts, max_steps, tols):
    """The same phases with every start side by side (for jax.grad / jit / vmap): each
    phase's solve runs without derivatives, and its answer is differentiated implicitly.
    Returns what `solve_host` does, with no target flagged as beyond."""
    best, steps = None, jnp.asarray(0)
    start_pose = init
    for layout in layouts:
        b0, p0, t0, tp0, ta0 = no_gradient((body, start_pose, ts, *tols))
        x, s = _all_starts_jit(b0, layout, p0, t0, starts, max_steps, tp0, ta0)
        a = _assess_jit(body, layout, start_pose, ts, x, s, *tols, True)
        steps = steps + s
        if best is not None and (a.pose.spine_target is None) != (best.pose.spine_target is None):
            # The limbs' phase leaves the spine as in init: name it as a target, so that
            # both phases' poses have one structure to select between.
            total = spine_angles(body, body.spine, init).sum(0)
            best = eqx.tree_at(lambda b: b.pose.spine_target, best, total, is_leaf=is_none)
        best = a if best is None else _select(better(a, best), a, best)
        start_pose = best.pose
    beyond = np.zeros(ts.point_xyz.shape[0], bool)
    return best, steps, beyond
