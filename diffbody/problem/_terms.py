"""A problem's terms on the point kernel (docs/design.md, section 6, "Terms").

Each term of a reach problem (the point effectors, the axis targets, the spheres the
constraints read, the centre of gravity) declares the points of the body it needs, as the
point kernel's rows (slots, offsets, heights), and how its value follows from their world
positions. `place` walks the body once for every term of a problem and hands each its
value: no term counts another's rows.
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._body import Body
from ._points import tree_points
from ._targets import TargetSet
from ._tree import effector_rows


def _points(q: Array) -> Array:
    return q


@dataclass(frozen=True)
class Term:
    """The kernel's points of one term and its value from their world positions."""

    slots: np.ndarray | Array  # (k,) int: the problem's chain or base slots
    offsets: Array  # (k, 3) m, in their segments' frames
    heights: Array  # (k,) m, along their segments (the twist's share)
    value: Callable[[Array], Array] = _points  # (k, 3) world points -> the term's value


def place(problem, x: Array, terms: Mapping) -> dict:
    """Every term's value for the free vector x of `problem`, from one call of the point
    kernel over all their points (`tree_points`)."""
    terms = dict(terms)
    sizes = [t.slots.shape[0] for t in terms.values()]
    if not sum(sizes):
        return {name: t.value(jnp.zeros((0, 3), x.dtype)) for name, t in terms.items()}
    slots = [t.slots for t in terms.values()]
    concat = np.concatenate if all(isinstance(s, np.ndarray) for s in slots) else jnp.concatenate
    offsets = jnp.concatenate([jnp.asarray(t.offsets, x.dtype) for t in terms.values()])
    heights = jnp.concatenate([jnp.asarray(t.heights, x.dtype) for t in terms.values()])
    q = tree_points(concat(slots), problem, problem.body.lengths, offsets, heights, x)
    parts = jnp.split(q, np.cumsum(sizes)[:-1])
    return {name: t.value(part) for (name, t), part in zip(terms.items(), parts)}


def mass_mean(body: Body, centroids: Array) -> Array:
    """The center of gravity (3,) of the segments' world centroids (n_seg, 3)."""
    total = jnp.sum(body.masses)
    return (body.masses / jnp.where(total > 0, total, 1.0)) @ centroids


def target_terms(problem, targets: TargetSet) -> tuple[list[Term], Term]:
    """The point effectors' terms, each of value (k, 3), and the axis targets' term, of
    value (n_a, 3). On a plan, one term of its point rows and one of its axis rows
    (`_tree.effector_rows`, data); else one term per effector of the layout: a joint, a
    feature on its sphere, or the center of gravity (the mass-weighted mean of every
    segment's centroid: the whole tree is walked for it). An axis is the difference of a
    point at its local direction (turned by the segment's whole twist) and the segment's
    proximal joint."""
    b = problem.body
    if problem.plan is not None:
        points, axes = effector_rows(b, problem.slot_of(), problem.plan, targets)
        return [Term(*points)], Term(*axes, _difference)
    lay = problem.layout
    n_j, n_f = b.n_joints, len(b.feature_names)
    terms = []
    for index, slot in zip(lay.points, lay.point_slot):
        one = np.asarray([slot])
        if index == n_j + n_f:
            every = np.asarray([lay.chain.position(s) for s in range(b.n_segments)], int)
            terms.append(Term(every, b.centroids, b.centroids[:, 2], _cog(b, keep_axis=True)))
        elif index == 0:
            terms.append(Term(one, jnp.zeros((1, 3)), jnp.zeros(1)))
        elif index < n_j:
            L = b.lengths[index - 1]
            terms.append(Term(one, jnp.stack([0.0 * L, 0.0 * L, L])[None], L[None]))
        else:
            sph = b.feature_sphere[index - n_j]
            origin = b.sphere_origins[sph]
            offset = origin + b.sphere_radii[sph] * b.feature_directions[index - n_j]
            terms.append(Term(one, offset[None], origin[2:3]))
    n_a = len(lay.axis_slot)
    seg = np.asarray(problem.slot_segments())[np.asarray(lay.axis_slot, int)]
    zeros = jnp.zeros((n_a, 3), targets.axis_local.dtype)
    axes = Term(
        np.asarray(lay.axis_slot * 2, int),
        jnp.concatenate([targets.axis_local, zeros]),
        jnp.concatenate([b.lengths[seg], zeros[:, 0]]),
        _difference,
    )
    return terms, axes


def sphere_term(problem, spheres: tuple[int, ...]) -> Term:
    """The centres (k, 3) of the spheres a problem's constraints read."""
    b, lay = problem.body, problem.layout
    sph = np.asarray(spheres, int)
    seg = np.asarray(b.sphere_segment, int)[sph]
    slots = np.asarray([lay.read_slot[s] for s in seg], int)
    return Term(slots, b.sphere_origins[sph], b.sphere_origins[sph, 2])


def cog_term(problem) -> Term:
    """The center of gravity (3,), from every segment's centroid: in the chain (the full
    tree), or read by the constraints."""
    b, lay = problem.body, problem.layout
    if lay.full:
        slots = [lay.chain.position(s) for s in range(b.n_segments)]
    else:
        slots = list(lay.read_slot)
    return Term(np.asarray(slots, int), b.centroids, b.centroids[:, 2], _cog(b))


def _difference(q: Array) -> Array:
    """The first half of the points less the second."""
    half = q.shape[0] // 2
    return q[:half] - q[half:]


def _cog(body: Body, keep_axis: bool = False) -> Callable[[Array], Array]:
    """The center of gravity of world centroids: (3,), or (1, 3) with `keep_axis`."""
    if keep_axis:
        return lambda centroids: mass_mean(body, centroids)[None]
    return lambda centroids: mass_mean(body, centroids)
