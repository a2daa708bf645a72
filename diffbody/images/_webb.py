"""Webb's static analysis of moving jointed objects (seed 003, III B; docs/design.md, section
8), faithfully: `webb`, `perpendicular_foot`, `ray_sphere`, `true_reflections`.

Camera frame (`Pinhole`): the pinhole at the origin, the focal plane at z = f (px), image
points (u, v) in px; lengths and joints in m. In each frame, top-down through the `JointTree`,
a part's ending point lies on the ray through (u, v, f) and on the sphere of the part's lower
bound r about its starting point: the quadratic formula gives two points, its reflections,
numbered 0 = near (toward the camera) and 1 = far, and given (the seed's assumption 1). If
the ray misses the sphere, r rises to formula (1), the starting point's distance from the
ray; the ending point is the foot of the perpendicular (formula (2)), and the bounds of every
part below (as III A defines "below", not only the children) restart from zero. Every bound
starts at zero. Under the seed's conditions the lengths become exact (its theorem).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..files._webb_files import FAR, NEAR
from ._joint_tree import JointTree

MISSED = -1  # a reflection code beside NEAR and FAR: the ray missed, formula (1) used


class WebbResult(eqx.Module):
    """What the algorithm computes for one sequence (or a batch: leading axes), camera frame."""

    lengths: Float[Array, "*b n_parts"]  # m, the lower bounds after the last frame
    bounds: Float[Array, "*b n_frames n_parts"]  # m, the lower bound after each frame
    joints: Float[Array, "*b n_frames n_obs 3"]  # m, the joints as computed in each frame
    reflections: Int[Array, "*b n_frames n_parts"]  # NEAR, FAR, or MISSED (formula (1))
    in_front: Bool[Array, "*b n_frames"]  # every computed joint has z > 0


def rays(uv: Float[ArrayLike, "*b 2"], focal: ArrayLike) -> Float[Array, "*b 3"]:
    """(u, v, f): the direction of the ray through an image point (px, focal in px)."""
    uv = jnp.asarray(uv)
    f = jnp.broadcast_to(jnp.asarray(focal, uv.dtype), uv.shape[:-1])
    return jnp.concatenate([uv, f[..., None]], axis=-1)


def perpendicular_foot(
    start: Float[ArrayLike, "*b 3"], ray: Float[ArrayLike, "*b 3"]
) -> tuple[Float[Array, "*b"], Float[Array, "*b"]]:
    """Seed 003, formulas (2) and (1): the ray parameter p = (ux + vy + fz) / (u^2 + v^2 +
    f^2) of the foot of the perpendicular from `start` = (x, y, z) to the ray through
    (u, v, f), and its distance r = |start - p (u, v, f)| (the smallest length a part from
    `start` can have and end on the ray)."""
    start, ray = jnp.asarray(start), jnp.asarray(ray)
    p = jnp.sum(ray * start, -1) / jnp.sum(ray * ray, -1)
    gap = start - p[..., None] * ray
    sq = jnp.sum(gap * gap, -1)
    tiny = sq <= jnp.finfo(sq.dtype).tiny
    return p, jnp.where(tiny, 0.0, jnp.sqrt(jnp.where(tiny, 1.0, sq)))


def ray_sphere(
    start: Float[ArrayLike, "*b 3"], ray: Float[ArrayLike, "*b 3"], radius: ArrayLike
) -> tuple[Float[Array, "*b 2"], Bool[Array, "*b"]]:
    """The ray parameters (near, far) where the ray meets the sphere of `radius` about
    `start` (the quadratic formula of III B.1, in the stable form p -+ sqrt(r^2 - d^2)/|w|),
    and whether it meets it. Where it misses, both are the foot of the perpendicular.
    Gradients stay finite at tangency."""
    p, d = perpendicular_foot(start, ray)
    disc = jnp.asarray(radius) ** 2 - d**2
    hit = disc >= 0
    pos = disc > 0
    h = jnp.where(pos, jnp.sqrt(jnp.where(pos, disc, 1.0)), 0.0) / jnp.linalg.norm(ray, axis=-1)
    return jnp.stack([p - h, p + h], -1), hit


def webb_kernel(
    tree: JointTree,
    uv: Float[Array, "n_frames n_obs 2"],
    root_depth: Float[Array, " n_frames"],
    focal: Float[Array, ""],
    reflections: Int[Array, "n_frames n_parts"],
) -> WebbResult:
    """The algorithm on one sequence, a `lax.scan` over frames (no input checks; see
    `webb`). Parts of one level of the tree are handled together: none lies below another."""
    P = tree.n_parts
    dtype = uv.dtype
    w_all = rays(uv, focal)  # (T, J, 3)

    # Parts level by level, each level gathering its starting points from the points
    # computed so far (a static index into their concatenation: no scatter in the loop).
    order = np.concatenate([np.asarray(level) for level in tree.levels])
    slot = {tree.root: 0}  # joint -> row in the concatenated points
    for k in order:
        slot[tree.part_end[k]] = len(slot)
    joint_rows = np.asarray([slot[j] for j in range(tree.n_joints)])
    part_rows = np.argsort(order)  # part k's row in level order
    levels = [np.asarray(level) for level in tree.levels]

    def frame(r_prev, inputs):
        w, depth, chosen = inputs
        points = [w[tree.root][None] * depth / focal]
        changed, bounds, codes = [], [], []
        for k in levels:
            s_rows = np.asarray([slot[j] for j in np.asarray(tree.part_start)[k]])
            above = np.asarray(tree.part_parent)[k]
            S = jnp.concatenate(points)[s_rows]
            if changed:  # a part whose part above changed this frame starts again from zero
                done = jnp.concatenate(changed)
                reset = jnp.where(above >= 0, done[part_rows[np.maximum(above, 0)]], False)
            else:
                reset = jnp.zeros(len(k), bool)
            r = jnp.where(reset, 0.0, r_prev[k])
            W = w[np.asarray(tree.part_end)[k]]
            p, d = perpendicular_foot(S, W)
            miss = d > r
            t_both, _ = ray_sphere(S, W, r)
            t = jnp.where(miss, p, jnp.where(chosen[k] == FAR, t_both[:, 1], t_both[:, 0]))
            points.append(t[:, None] * W)
            bounds.append(jnp.where(miss, d, r))
            changed.append(reset | miss)
            codes.append(jnp.where(miss, MISSED, chosen[k]))
        pos = jnp.concatenate(points)[joint_rows]
        r_now = jnp.concatenate(bounds)[part_rows]
        return r_now, (pos, r_now, jnp.concatenate(codes)[part_rows])

    r0 = jnp.zeros(P, dtype)
    lengths, (joints, bounds, codes) = jax.lax.scan(
        frame, r0, (w_all, root_depth, reflections.astype(jnp.int32))
    )
    return WebbResult(
        lengths=lengths,
        bounds=bounds,
        joints=joints,
        reflections=codes,
        in_front=jnp.all(joints[..., 2] > 0, axis=-1),
    )


@eqx.filter_jit
def _webb_jit(tree, uv, root_depth, focal, reflections):
    root_depth = eqx.error_if(
        root_depth, jnp.any(~(root_depth > 0)), "webb: the reference depth must be > 0 (m)"
    )
    focal = eqx.error_if(focal, jnp.any(~(focal > 0)), "webb: the focal length must be > 0 (px)")
    flat = uv.shape[:-3]
    n = int(np.prod(flat))
    T, J = uv.shape[-3:-1]
    out = jax.vmap(lambda a, b, c, d: webb_kernel(tree, a, b, c, d))(
        uv.reshape(n, T, J, 2),
        root_depth.reshape(n, T),
        jnp.broadcast_to(focal, flat).reshape(n),
        reflections.reshape(n, T, tree.n_parts),
    )
    return jax.tree.map(lambda x: x.reshape(flat + x.shape[1:]), out)


def check_sequence(
    tree: JointTree, uv, root_depth, focal, what: str = "webb"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Host checks of an image sequence (..., T, J, 2) px, depths (..., T) m, focal (...) px:
    shapes, finite values, depth and focal length > 0. Errors name the entry and the fix."""
    uv, depth, f = (np.asarray(a, dtype=float) for a in (uv, root_depth, focal))
    if uv.ndim < 3 or uv.shape[-1] != 2 or uv.shape[-2] != tree.n_joints:
        raise ValueError(
            f"{what}: image points must have shape (..., n_frames, {tree.n_joints}, 2) "
            f"(u, v in px for each of the tree's {tree.n_joints} joints), got {uv.shape}"
        )
    if depth.shape != uv.shape[:-2]:
        raise ValueError(
            f"{what}: root_depth must have shape {uv.shape[:-2]} (one depth per frame), "
            f"got {depth.shape}"
        )
    if f.shape not in ((), uv.shape[:-3]):
        raise ValueError(f"{what}: focal must be a number or shape {uv.shape[:-3]}, got {f.shape}")
    if uv.shape[-3] < 1:
        raise ValueError(f"{what}: the sequence has no frames")

    def frame(i: tuple[int, ...]) -> str:
        seq = f" of sequence {i[:-1] if len(i) > 2 else i[0]}" if len(i) > 1 else ""
        return f"frame {i[-1]}{seq}"

    bad = np.argwhere(~np.isfinite(uv))
    if len(bad):
        i = tuple(int(x) for x in bad[0])
        raise ValueError(
            f"{what}: the image point of joint {tree.names[i[-2]]!r} in {frame(i[:-2])} is "
            f"{float(uv[i]):g}; every joint needs a finite position (px) in every frame"
        )
    bad = np.argwhere(~(np.isfinite(depth) & (depth > 0)))
    if len(bad):
        i = tuple(int(x) for x in bad[0])
        raise ValueError(
            f"{what}: the reference depth of {frame(i)} is {float(depth[i]):g}; it must be a "
            "finite number > 0 m (the reference joint lies in front of the camera)"
        )
    if not np.all(np.isfinite(f) & (f > 0)):
        raise ValueError(f"{what}: the focal length must be a finite number > 0 px, got {focal!r}")
    return uv, depth, f


def webb(
    tree: JointTree,
    uv: Float[ArrayLike, "*b n_frames n_obs 2"],
    root_depth: Float[ArrayLike, "*b n_frames"],
    focal: ArrayLike,
    reflections: Int[ArrayLike, "*b n_frames n_parts"],
) -> WebbResult:
    """Webb's algorithm (seed 003, III B) on one sequence or a batch (leading axes).

    Args:
        tree: the observed skeleton; its root is the reference joint.
        uv: image points (px from the principal point, v down) of every joint per frame.
        root_depth: the reference joint's depth z (m) per frame.
        focal: focal length (px), one per sequence or shared.
        reflections: which reflection each part takes in each frame, NEAR (0) or FAR (1)
            (the seed assumes them known; `diffbody.true_reflections` gives them for a
            synthetic sequence, `diffbody.choose_reflections` chooses them by continuity).

    Returns:
        `WebbResult`: the lengths (the final lower bounds), the bound after every frame,
        the joints computed in every frame (camera frame, m) and the reflection codes used
        (MISSED where formula (1) raised the bound). Jitted; batches are vmapped.
    """
    uv, depth, f = check_sequence(tree, uv, root_depth, focal)
    refl = np.asarray(reflections)
    if refl.shape != uv.shape[:-2] + (tree.n_parts,):
        raise ValueError(
            f"webb: reflections must have shape {uv.shape[:-2] + (tree.n_parts,)} (one per "
            f"part and frame), got {refl.shape}"
        )
    if not np.all((refl == NEAR) | (refl == FAR)):
        raise ValueError("webb: reflections must be 0 (near) or 1 (far)")
    dtype = jnp.zeros(()).dtype
    return _webb_jit(
        tree,
        jnp.asarray(uv, dtype),
        jnp.asarray(depth, dtype),
        jnp.asarray(f, dtype),
        jnp.asarray(refl, jnp.int32),
    )


def true_reflections(
    tree: JointTree, joints: Float[ArrayLike, "*b n_frames n_obs 3"]
) -> Int[Array, "*b n_frames n_parts"]:
    """The reflection each part takes in true joint positions (camera frame): FAR where its
    ending point E lies beyond the foot of the perpendicular from its starting point S on
    the ray through E, i.e. where E . (E - S) > 0; NEAR otherwise."""
    joints = jnp.asarray(joints)
    E = joints[..., np.asarray(tree.part_end), :]
    S = joints[..., np.asarray(tree.part_start), :]
    return jnp.where(jnp.sum(E * (E - S), -1) > 0, FAR, NEAR).astype(jnp.int32)
