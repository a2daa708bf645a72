"""The one walk of diffbody's segment tree (docs/design.md, section 3, "The one walk").

A `Chain` is built once on the host: a set of segments in topological order, each with the
slot its parent's state comes from. Slots 0..m-1 are the chain's own segments; slots m...
are the *bases*, fixed states the chain hangs from (the world for the whole body; for a
solver, the frames of the segments above the first unknown, read once from the start).

`walk` is the only function that composes posed frames down the tree: forward kinematics and
the solvers' residuals (and through them the post-projection, pictures and exports), local
frames and the posture from joints call it with their own per-segment step. The standard
position needs no walk (every frame is the standard cross of axes): `_body.rest_geometry` sums
it on the host, and anthropometry's `rest_points` as one product with an ancestor matrix.
"""

import functools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

# Unrolled or scanned: a solver's short chains are unrolled level by level, faster to run at
# the same compile time; the whole body's levels are scanned, faster to compile
# (docs/benchmarks.md, "Forward kinematics and Bendspine").
UNROLL_LEVELS = 8


@dataclass(frozen=True)
class Chain:
    """Static structure of a walk (hashable: a compile-time constant).

    segments: global segment indices, parents before children.
    parent_slot: per segment, the slot of its parent's state (< len(segments): a chain
        segment; otherwise base `slot - len(segments)`).
    levels: positions into `segments`, grouped by depth (a level's parents are all in
        earlier levels or bases).
    n_bases: how many base states the walk takes.
    """

    segments: tuple[int, ...]
    parent_slot: tuple[int, ...]
    levels: tuple[tuple[int, ...], ...]
    n_bases: int

    @property
    def size(self) -> int:
        return len(self.segments)

    def position(self, segment: int) -> int:
        """Where a global segment index sits in the chain."""
        return self.segments.index(segment)


def make_chain(parent: Sequence[int], segments: Iterable[int], bases: Sequence[int]) -> Chain:
    """The chain of `segments` (global indices, any order) of a tree with `parent` (-1 at the
    top), hanging from `bases`: global segment indices (or -1, the world) whose states are
    given to `walk`. Every segment's parent must be a chain segment or a base."""
    parent = [int(p) for p in parent]
    depth: dict[int, int] = {}

    def depth_of(i: int) -> int:
        if i not in depth:
            depth[i] = 0 if parent[i] < 0 else depth_of(parent[i]) + 1
        return depth[i]

    order = sorted({int(s) for s in segments}, key=lambda i: (depth_of(i), i))
    bases = [int(b) for b in bases]
    slot = {s: k for k, s in enumerate(order)}
    slot.update({b: len(order) + k for k, b in enumerate(bases)})
    missing = [s for s in order if parent[s] not in slot]
    if missing:
        raise ValueError(f"make_chain: segments {missing} hang from neither the chain nor a base")
    level_of = {}
    for k, s in enumerate(order):
        p = parent[s]
        level_of[k] = 0 if p in bases else level_of[slot[p]] + 1
    levels = [[] for _ in range(max(level_of.values(), default=-1) + 1)]
    for k in range(len(order)):
        levels[level_of[k]].append(k)
    return Chain(
        segments=tuple(order),
        parent_slot=tuple(slot[parent[s]] for s in order),
        levels=tuple(tuple(level) for level in levels),
        n_bases=len(bases),
    )


def on_paths(parent: Sequence[int], nodes: Iterable[int]) -> np.ndarray:
    """(k, n) 0/1: node i of a tree with `parent` (n,; -1 or out of range at a top) lies on
    node k's path to its top, itself included; a zero row for a node that is not in the
    tree (-1 or out of range). The one ancestor matrix: of a point's segments (the point
    kernel), of the standard position's joints (scaling), of an image skeleton's parts."""
    parent = [int(p) for p in parent]
    n = len(parent)
    nodes = [int(k) for k in nodes]
    A = np.zeros((len(nodes), n))
    for row, i in enumerate(nodes):
        while 0 <= i < n:
            A[row, i] = 1.0
            i = parent[i]
    return A


def walk(chain: Chain, step: Callable, bases, xs, *, unroll: bool | None = None):
    """Walk the chain: state_i = step(state of i's parent, xs_i), parents first.

    Args:
        chain: the static structure.
        step: (parent state, per-segment input) -> state, for one segment; a pytree of
            arrays with the same structure and shapes as one base state.
        bases: base states, each leaf with a leading axis `chain.n_bases`.
        xs: per-segment inputs, each leaf with a leading axis `chain.size` (chain order).
        unroll: walk level by level in Python (True) or with one `lax.scan` over the levels
            padded to one width (False); default: unrolled up to `UNROLL_LEVELS` levels.

    Returns:
        The states of the chain's segments, each leaf with a leading axis `chain.size`.
    """
    m = chain.size
    levels = chain.levels
    if unroll is None:
        unroll = len(levels) <= UNROLL_LEVELS
    take = lambda tree, i: jax.tree.map(lambda a: a[i], tree)  # noqa: E731
    stack = lambda trees: jax.tree.map(lambda *a: jnp.stack(a), *trees)  # noqa: E731
    if unroll:
        # One state per slot in a Python list: a level of one segment (most of a limb) is a
        # plain call of `step`, with no gather or scatter in the traced graph.
        slots = [None] * m + [take(bases, k) for k in range(chain.n_bases)]
        for level in levels:
            if len(level) == 1:
                (i,) = level
                slots[i] = step(slots[chain.parent_slot[i]], take(xs, i))
                continue
            parents = stack([slots[chain.parent_slot[i]] for i in level])
            new = jax.vmap(step)(parents, take(xs, np.asarray(level, int)))
            for j, i in enumerate(level):
                slots[i] = take(new, j)
        if not m:
            return jax.tree.map(lambda b: b[:0], bases)
        return stack(slots[:m])
    # Scanned: all states live in one array per leaf (the chain's m slots, the bases, and a
    # scratch slot that the padding of a level writes to).
    states = jax.tree.map(
        lambda b: jnp.concatenate([jnp.zeros((m,) + b.shape[1:], b.dtype), b, b[:1]]), bases
    )
    scratch = m + chain.n_bases
    parent_slot = np.asarray(chain.parent_slot + (scratch,), int)
    level_step = jax.vmap(step)
    if levels:
        width = max(len(level) for level in levels)
        idx = np.full((len(levels), width), scratch)
        for k, level in enumerate(levels):
            idx[k, : len(level)] = level
        par = parent_slot[np.minimum(idx, m)]
        par = np.where(idx < m, par, scratch)
        xs_pad = jax.tree.map(lambda a: jnp.concatenate([a, a[:1]]), xs)

        def scan_step(states, ij):
            i, p = ij
            x = jax.tree.map(lambda a: a[jnp.minimum(i, m)], xs_pad)
            new = level_step(take(states, p), x)
            return jax.tree.map(lambda s, v: s.at[i].set(v), states, new), None

        states, _ = jax.lax.scan(scan_step, states, (jnp.asarray(idx), jnp.asarray(par)))
    return jax.tree.map(lambda s: s[:m], states)


@functools.cache
def _below_top(parent: tuple[int, ...]) -> Chain:
    return make_chain(parent, range(1, len(parent)), [0])


def walk_below_top(parent: Sequence[int], step: Callable, top, xs):
    """`walk` over every segment below segment 0 (the whole body), in global order: `top`
    is segment 0's state, `xs` the per-segment inputs with a leading axis of all n
    segments (row 0 unused). Returns every segment's state (n, ...), row 0 `top`."""
    chain = _below_top(tuple(int(p) for p in parent))
    seg = np.asarray(chain.segments, int)
    out = walk(
        chain, step, jax.tree.map(lambda a: a[None], top), jax.tree.map(lambda a: a[seg], xs)
    )
    back = np.argsort(seg)
    return jax.tree.map(lambda t, o: jnp.concatenate([t[None], o[back]]), top, out)
