"""Reflections chosen by continuity over time (beyond seed 003, which assumes them known;
docs/design.md, section 8): `choose_reflections`.

Offline, part by part from the reference down: once its starting point's whole trajectory is
known, a part's length is formula (1) over all frames (no reset, no order dependence), its
two candidate ending points in every frame are taken at that length, and dynamic programming
(Viterbi) picks the sequence of choices whose ending point has the least squared velocity or
acceleration (m per frame). A mirrored trajectory is as smooth as the true one, so each part's
branch stays open unless `anchor` gives the reflections in one frame. A part never seen
perpendicular to its ray gets too short a length, and continuity may then switch branches
where its two candidates meet.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._joint_tree import JointTree
from ._webb import FAR, NEAR, check_sequence, perpendicular_foot, ray_sphere, rays


class ReflectionChoice(eqx.Module):
    """Reflections chosen by continuity, with the lengths and joints they give (camera
    frame); leading batch axes when batched."""

    reflections: Int[Array, "*b n_frames n_parts"]  # NEAR (0) or FAR (1)
    lengths: Float[Array, "*b n_parts"]  # m, formula (1) over all frames
    median_lengths: Float[Array, "*b n_parts"]  # m, its largest 3-frame median (robust)
    joints: Float[Array, "*b n_frames n_obs 3"]  # m
    separation: Float[Array, "*b n_frames n_parts"]  # m, distance between the two candidates


def _viterbi(cand: Float[Array, "n_frames 2 3"], order: int, anchor: Array) -> Array:
    """The choice (T,) in {0, 1} whose points cand[t, choice] have the smallest sum of
    squared first (order 1) or second (order 2) differences; `anchor` (T, 2) adds a cost
    per frame and choice (0 or inf, to pin a choice)."""
    T = cand.shape[0]
    if order == 1 or T < 3:
        # cost[s_prev, s] of moving from cand[t-1, s_prev] to cand[t, s]
        def step(acc, x):
            prev, now, pin = x
            c = acc[:, None] + jnp.sum((now[None] - prev[:, None]) ** 2, -1)
            return jnp.min(c, 0) + pin, jnp.argmin(c, 0)

        acc, back = jax.lax.scan(step, anchor[0], (cand[:-1], cand[1:], anchor[1:]))
        last = jnp.argmin(acc)

        def walk(s, b):
            return b[s], s

        first, path = jax.lax.scan(walk, last, back, reverse=True)
        return jnp.concatenate([first[None], path])
    # Order 2: the state is (s_{t-1}, s_t), index 2 * s_{t-1} + s_t.
    a = np.array([0, 0, 1, 1])  # s_{t-1} of state i
    b = np.array([0, 1, 0, 1])  # s_t of state i
    init = anchor[0][a] + anchor[1][b]

    def step(acc, x):
        p2, p1, now, pin = x
        # from state i = (a, b) to state j = (b', c) needs b == b'
        step = now[b][None] - 2 * p1[b][:, None] + p2[a][:, None]
        acc_ij = acc[:, None] + jnp.sum(step**2, -1)
        acc_ij = jnp.where(b[:, None] == a[None, :], acc_ij, jnp.inf)
        return jnp.min(acc_ij, 0) + pin[b], jnp.argmin(acc_ij, 0)

    acc, back = jax.lax.scan(step, init, (cand[:-2], cand[1:-1], cand[2:], anchor[2:]))
    last = jnp.argmin(acc)

    def walk(s, bp):
        return bp[s], s

    first, states = jax.lax.scan(walk, last, back, reverse=True)
    states = jnp.concatenate([first[None], states])  # state at frames 1 .. T-1
    return jnp.concatenate([jnp.asarray(a)[states[:1]], jnp.asarray(b)[states]])


def choose_kernel(
    tree: JointTree,
    uv: Float[Array, "n_frames n_obs 2"],
    root_depth: Float[Array, " n_frames"],
    focal: Float[Array, ""],
    anchor: Int[Array, " n_parts"],
    anchor_frame: int = 0,
    order: int = 2,
    given: Int[Array, "n_frames n_parts"] | None = None,
) -> ReflectionChoice:
    """`choose_reflections` on one sequence (no input checks). `anchor` (P,) pins the
    reflection of each part at `anchor_frame` (NEAR or FAR; -1 leaves it free); `given`
    (T, P) takes those reflections instead of choosing (the same offline geometry)."""
    T = uv.shape[0]
    w = rays(uv, focal)  # (T, J, 3)
    pos = jnp.zeros((T, tree.n_joints, 3), uv.dtype)
    pos = pos.at[:, tree.root].set(w[:, tree.root] * (root_depth / focal)[:, None])
    P = tree.n_parts
    lengths = jnp.zeros(P, uv.dtype)
    median_lengths = jnp.zeros(P, uv.dtype)
    choice = jnp.zeros((T, P), jnp.int32)
    separation = jnp.zeros((T, P), uv.dtype)
    for level in tree.levels:
        k = np.asarray(level)
        s = np.asarray(tree.part_start)[k]
        e = np.asarray(tree.part_end)[k]
        S, W = pos[:, s], w[:, e]  # (T, n, 3)
        _, d = perpendicular_foot(S, W)
        L = jnp.max(d, axis=0)  # formula (1) over every frame
        if T >= 3:  # the largest 3-frame median: one wrong detection cannot set it
            med = jnp.max(jnp.median(jnp.stack([d[:-2], d[1:-1], d[2:]]), axis=0), axis=0)
        else:
            med = L
        median_lengths = median_lengths.at[k].set(med)
        t_both, _ = ray_sphere(S, W, L[None])  # (T, n, 2)
        cand = t_both[..., None] * W[:, :, None, :]  # (T, n, 2, 3)
        pin = jnp.where(
            (anchor[k][None, :, None] >= 0)
            & (jnp.arange(T)[:, None, None] == anchor_frame)
            & (jnp.arange(2)[None, None, :] != anchor[k][None, :, None]),
            jnp.inf,
            0.0,
        )  # (T, n, 2)
        if given is None:
            c = jax.vmap(lambda x, y: _viterbi(x, order, y), in_axes=(1, 1), out_axes=1)(cand, pin)
        else:
            c = given[:, k]
        pos = pos.at[:, e].set(jnp.where((c == FAR)[..., None], cand[:, :, 1], cand[:, :, 0]))
        lengths = lengths.at[k].set(L)
        choice = choice.at[:, k].set(c.astype(jnp.int32))
        separation = separation.at[:, k].set(
            jnp.linalg.norm(cand[:, :, 1] - cand[:, :, 0], axis=-1)
        )
    return ReflectionChoice(
        reflections=choice,
        lengths=lengths,
        median_lengths=median_lengths,
        joints=pos,
        separation=separation,
    )


def check_anchor(tree: JointTree, anchor, shape, anchor_frame: int, order: int, what: str):
    """The anchor as an int array (-1 where free), checked with `order` and `anchor_frame`
    against an image sequence of `shape` (..., T, J, 2)."""
    if order not in (1, 2):
        raise ValueError(f"{what}: order must be 1 (velocity) or 2 (acceleration), got {order!r}")
    T = shape[-3]
    if not -T <= anchor_frame < T:
        raise ValueError(f"{what}: anchor_frame {anchor_frame} is not a frame (0..{T - 1})")
    lead = tuple(shape[:-3])
    a = np.full(lead + (tree.n_parts,), -1) if anchor is None else np.asarray(anchor)
    if a.shape not in ((tree.n_parts,), lead + (tree.n_parts,)):
        raise ValueError(
            f"{what}: anchor must have shape ({tree.n_parts},) or {lead + (tree.n_parts,)}, "
            f"got {a.shape}"
        )
    if not np.all((a == NEAR) | (a == FAR) | (a == -1)):
        raise ValueError(f"{what}: anchor entries must be 0 (near), 1 (far) or -1 (free)")
    return a


def over_sequences(one, tree: JointTree, uv, root_depth, focal, anchor):
    """`one(uv, root_depth, focal, anchor)` of one sequence, vmapped over the leading batch
    axes of `uv` (..., T, J, 2); focal and anchor broadcast to every sequence."""
    flat = uv.shape[:-3]
    n = int(np.prod(flat))
    T, J = uv.shape[-3:-1]
    out = jax.vmap(one)(
        uv.reshape(n, T, J, 2),
        root_depth.reshape(n, T),
        jnp.broadcast_to(focal, flat).reshape(n),
        jnp.broadcast_to(anchor, flat + (tree.n_parts,)).reshape(n, tree.n_parts),
    )
    return jax.tree.map(lambda x: x.reshape(flat + x.shape[1:]), out)


@eqx.filter_jit
def _choose_jit(tree, uv, root_depth, focal, anchor, anchor_frame, order):
    def one(a, b, c, d):
        return choose_kernel(tree, a, b, c, d, anchor_frame, order)

    return over_sequences(one, tree, uv, root_depth, focal, anchor)


def choose_reflections(
    tree: JointTree,
    uv: Float[ArrayLike, "*b n_frames n_obs 2"],
    root_depth: Float[ArrayLike, "*b n_frames"],
    focal: ArrayLike,
    *,
    anchor: Int[ArrayLike, "*b n_parts"] | None = None,
    anchor_frame: int = 0,
    order: int = 2,
) -> ReflectionChoice:
    """Reflections by continuity (module docstring) for one sequence or a batch.

    Args:
        tree, uv, root_depth, focal: as for `diffbody.webb`.
        anchor: the reflections (NEAR 0 or FAR 1, -1 for unknown) of every part in frame
            `anchor_frame`, when known; None leaves every part's branch to continuity.
        order: 1 minimises the joints' squared velocities, 2 their accelerations.

    Returns:
        `ReflectionChoice`: reflections (T, P), the lengths (formula (1) over all frames,
        each part after the whole trajectory of the part above it), their robust version
        (the largest 3-frame median of formula (1): one wrong detection cannot lengthen a
        part; a smooth maximum loses a fraction of the change over one frame), the joints
        (camera frame) and, per frame and part, how far apart the two candidates were (m; where
        they nearly coincide the choice does not matter).
    """
    uv, depth, f = check_sequence(tree, uv, root_depth, focal, "choose_reflections")
    a = check_anchor(tree, anchor, uv.shape, anchor_frame, order, "choose_reflections")
    T = uv.shape[-3]
    dtype = jnp.zeros(()).dtype
    return _choose_jit(
        tree,
        jnp.asarray(uv, dtype),
        jnp.asarray(depth, dtype),
        jnp.asarray(f, dtype),
        jnp.asarray(a, jnp.int32),
        anchor_frame % T,
        order,
    )
