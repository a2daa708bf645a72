"""Lengths and 3D postures from several cameras of unknown placement (beyond seed 003;
docs/design.md, section 8): `lift_views_uncalibrated`, by the factorization of Tomasi and
Kanade (1992) under scaled orthography.

A camera far from the body relative to the body's depth sees it nearly in scaled
orthography: an image point is s_v R_v[:2] X + t_v, with the view's scale s_v (px per m),
rotation R_v and shift t_v unknown. Stacked over views (rows) and over every joint of every
frame (columns), the image points less each row's mean are a matrix of rank 3, M S, with M
(2V, 3) the views' scaled rows and S (3, TJ) the points. Its singular value decomposition
gives M and S up to an invertible A; A A^T follows from each view's two rows being
orthogonal and of equal length (linear in its six entries, the first view's rows of unit
length), and then S = A^-1 S_hat. What remains unknown: a rotation and a mirror image of the
whole (no view tells a figure from its reflection in orthography), and the scale in metres.
The scale comes from the population prior on the part lengths (`length_prior`): the factor
c that brings the log lengths c L nearest to the prior's mean in its own metric,
log c = (W 1) . (W (mean - log L)) / |W 1|^2.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._solver import least_squares_solver, solve
from .._statuses import FitStatus
from ._joint_tree import JointTree
from ._length_prior import LengthPrior, group_firsts
from ._lifting import LiftOptions, check_options

# The points' spread (in the first view's px) may exceed the first view's image spread by at
# most this factor: a body's depth is not five times its width in any view.
STRETCH = 5.0


class AffineLifting(eqx.Module):
    """A sequence lifted from views of unknown placement; leading batch axes when batched."""

    lengths: Float[Array, "*b n_parts"]  # m (scale from the prior)
    joints: Float[Array, "*b n_frames n_obs 3"]  # m, about their centroid (a rotation, a mirror)
    view_scales: Float[Array, "*b V"]  # px per m, each view's
    residual_rms: Float[Array, "*b"]  # px: the image points against the rank-3 fit
    status: Int[Array, "*b"]  # the metric upgrade's FitStatus; FAILED: stretched (`STRETCH`)


def _pairs(a: Array, b: Array) -> Array:
    """(..., 6) the coefficients of the symmetric Q's entries (q00, q01, q02, q11, q12,
    q22) in a Q b^T."""
    return jnp.stack(
        [
            a[..., 0] * b[..., 0],
            a[..., 0] * b[..., 1] + a[..., 1] * b[..., 0],
            a[..., 0] * b[..., 2] + a[..., 2] * b[..., 0],
            a[..., 1] * b[..., 1],
            a[..., 1] * b[..., 2] + a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 2],
        ],
        axis=-1,
    )


def factorize(uv: Float[Array, "V T J 2"]) -> tuple[Array, Array, Array, Array]:
    """(points (T, J, 3) in the first view's px, about their centroid, each view's scale
    relative to the first's (V,), the image points' RMS off the rank-3 fit (px), the
    metric fit's `FitStatus`)."""
    V, T, J, _ = uv.shape
    W = jnp.moveaxis(uv, -1, 1).reshape(2 * V, T * J)
    W = W - jnp.mean(W, axis=1, keepdims=True)
    U, sv, Vt = jnp.linalg.svd(W, full_matrices=False)
    root = jnp.sqrt(sv[:3])
    M, S = U[:, :3] * root, root[:, None] * Vt[:3]
    a, b = M[0::2], M[1::2]
    G = jnp.concatenate([_pairs(a, a) - _pairs(b, b), _pairs(a, b), _pairs(a[:1], a[:1])])
    rhs = jnp.zeros(G.shape[0], uv.dtype).at[-1].set(1.0)
    q = jnp.linalg.lstsq(G, rhs)[0]
    Q = jnp.stack([q[jnp.asarray(i)] for i in ([0, 1, 2], [1, 3, 4], [2, 4, 5])])
    # Where the views are not quite orthographic (a limb reaching toward a camera 3 m
    # away), the linear solution can be indefinite: A itself (Q = A A^T, definite by
    # construction) is then fitted to each view's constraints as ratios, from the linear
    # solution made definite.
    w, vec = jnp.linalg.eigh(Q)
    A0 = vec * jnp.sqrt(jnp.maximum(w, 1e-6 * jnp.max(w)))
    fit = solve(_metric_rows, least_squares_solver(1e-10), A0, (a, b), 100)
    A = fit.value
    X = jnp.linalg.solve(A, S).T.reshape(T, J, 3)
    rows = M @ A
    scales = jnp.linalg.norm(rows[0::2], axis=-1)
    off = W - M @ S
    # Far from orthographic, the constraints can be met by an A near singular: the points
    # then stretch along one axis far beyond what any view shows. That is a failure.
    stretched = jnp.max(jnp.std(X.reshape(-1, 3), 0)) > STRETCH * jnp.max(jnp.std(W[:2], 1))
    status = jnp.where(stretched, FitStatus.FAILED, fit.status).astype(jnp.int32)
    return X, scales, jnp.sqrt(jnp.mean(off**2) * 2), status


def _metric_rows(A: Array, rows: tuple[Array, Array]) -> Array:
    """Each view's rows a, b (V, 3) made orthogonal and of equal length by A, as ratios
    (scale-free, so that every view counts alike), and the first view's of unit length."""
    a, b = rows[0] @ A, rows[1] @ A
    aa, bb, ab = (jnp.sum(x * y, -1) for x, y in ((a, a), (b, b), (a, b)))
    return jnp.concatenate([(aa - bb) / (aa + bb), 2 * ab / (aa + bb), aa[:1] - 1.0])


def affine_kernel(tree: JointTree, uv: Float[Array, "V T J 2"], prior: LengthPrior):
    """`lift_views_uncalibrated` on one sequence (no input checks)."""
    X, scales, rms, status = factorize(uv)
    s, e = np.asarray(tree.part_start), np.asarray(tree.part_end)
    L = jnp.median(jnp.linalg.norm(X[:, e] - X[:, s], axis=-1), axis=0)  # px of view 0
    first = group_firsts(tree)
    w1 = prior.whiten @ jnp.ones(len(first), uv.dtype)
    r = prior.whiten @ (prior.mean - jnp.log(L[first]))
    c = jnp.exp(w1 @ r / (w1 @ w1))  # m per px of view 0
    return AffineLifting(c * L, c * X, scales / c, rms, status)


@eqx.filter_jit
def _affine_jit(tree, uv, prior):
    flat = uv.shape[:-4]
    n = int(np.prod(flat))
    out = jax.vmap(lambda a: affine_kernel(tree, a, prior))(uv.reshape((n,) + uv.shape[-4:]))
    return jax.tree.map(lambda x: x.reshape(flat + x.shape[1:]), out)


def lift_views_uncalibrated(
    tree: JointTree, uv: Float[ArrayLike, "*b V n_frames n_obs 2"], prior: LengthPrior
) -> AffineLifting:
    """Part lengths and 3D joints of a sequence seen by two or more cameras whose placement
    is not known, under scaled orthography (module docstring): the proportions are good
    where the cameras are far from the body relative to its depth (on the default body's
    walk, 2 % of length error 3 m away, 0.6 % 10 m away, where the prior's scale is right);
    the scale in metres is the population prior's guess, off by as much as the person's
    size is from what their proportions predict (benchmarks/lifting_prior.py).

    Args:
        tree: the observed joints.
        uv: image points (..., V, T, J, 2) px, every joint seen in every view and frame.
        prior: `length_prior(tree, sex)`, which gives the scale.

    Returns:
        `AffineLifting`: lengths (m), joints (m, about their centroid, in a frame of the
        first view's image axes and depth, up to a mirror image), each view's scale (px
        per m), the image points' RMS off the rank-3 fit (px; large where the views do
        not see one rigid motion) and the metric upgrade's `FitStatus` (FAILED where the
        views are too far from orthographic: the points stretch along one axis; then the
        figures mean nothing).
    """
    uv = np.asarray(uv, dtype=float)
    if uv.ndim < 4 or uv.shape[-1] != 2 or uv.shape[-2] != tree.n_joints or uv.shape[-4] < 2:
        raise ValueError(
            "lift_views_uncalibrated: image points must have shape (..., V >= 2 views, "
            f"n_frames, {tree.n_joints} joints, 2), got {uv.shape}"
        )
    bad = np.argwhere(~np.isfinite(uv))
    if len(bad):
        i = tuple(int(x) for x in bad[0])
        raise ValueError(
            f"lift_views_uncalibrated: the image point of joint {tree.names[i[-2]]!r} in "
            f"frame {i[-3]} of view {i[-4]} is {float(uv[i]):g}; the factorization needs "
            "every joint in every view and frame (lift_views takes NaN for unseen joints)"
        )
    check_options(LiftOptions(prior=prior), "lift_views_uncalibrated", tree)
    dtype = jnp.zeros(()).dtype
    prior = jax.tree.map(lambda a: jnp.asarray(a, dtype), prior)
    return _affine_jit(tree, jax.device_put(uv.astype(dtype)), prior)
