"""Joint refinement of lengths and postures from an image sequence (beyond seed 003;
docs/design.md, section 8): `refine`, and `lift`, the whole pipeline from Webb's estimate.

One least-squares problem over all frames, by the one Levenberg-Marquardt (`diffbody._solver`).
Unknowns: the log of every distinct length (m; left and right shared with `symmetric`),
optionally the log focal length (px), and per frame the reference joint's (x, y) (its depth is
known) and each part's direction as two coordinates in the plane tangent to its start (no
pole). Residuals, weighted by `LiftOptions`: reprojection (px) through a Cauchy loss; the
accelerations of every part and of the reference (m per frame^2), looser along the optical
axis; the log lengths toward the start (Webb's lengths are lower bounds); optionally the
body's hinge limits. Frames couple only through the accelerations and the lengths, so the
solver's linear solve is `_banded.BandedSchurCholesky`: each step in O(T n^3). The focal
length is weakly observable: refine it only from a close start.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float, Int

from .._chain import on_paths
from .._programs import compiled
from .._rotations import safe_normalize
from .._solver import least_squares_solver, solve
from ._banded import BandedSchurCholesky, FrameResiduals, FrameUnknowns
from ._joint_tree import JointTree
from ._length_prior import LengthPrior
from ._webb import check_sequence, rays


class Lifting(eqx.Module):
    """A refined sequence (camera frame); leading batch axes when batched."""

    lengths: Float[Array, "*b n_parts"]  # m
    joints: Float[Array, "*b n_frames n_obs 3"]  # m
    focal: Float[Array, "*b"]  # px (the given one unless refined)
    reprojection_rms: Float[Array, "*b"]  # px, over every joint and frame
    steps: Int[Array, "*b"]  # Levenberg-Marquardt steps taken
    status: Int[Array, "*b"]  # a FitStatus


class LiftOptions(eqx.Module):
    """Weights and switches of the refinement (module docstring). The weights are traced
    (changing them does not recompile); the switches are static."""

    pixel_sigma: float = 1.0  # px, the image noise expected
    accel_sigma: float = 0.0015  # m per frame^2, the accelerations expected across the view
    depth_accel_sigma: float | None = 0.02  # along the optical axis; None: accel_sigma
    robust: float | None = 3.0  # Cauchy scale in pixel sigmas; None: plain least squares
    length_sigma: float | None = 0.05  # log-length pull toward the start; None: free
    limit_sigma: float = 0.01  # the hinge rows' scale (cosine)
    symmetric: bool = eqx.field(default=True, static=True)  # left and right share a length
    limits: tuple[tuple[int, int, float], ...] = eqx.field(default=(), static=True)
    refine_focal: bool = eqx.field(default=False, static=True)
    # The population prior on the log lengths (`length_prior`); with it the pull toward the
    # start holds the lengths only from below (Webb's are lower bounds). Needs `symmetric`.
    prior: LengthPrior | None = None
    max_steps: int = eqx.field(default=8, static=True)
    tol: float = eqx.field(default=1e-2, static=True)  # optimistix rtol = atol (RMS norm)


def tangent_basis(d: Array) -> tuple[Array, Array]:
    """Two unit vectors spanning the plane perpendicular to unit vectors d (..., 3)."""
    ax = jnp.argmin(jnp.abs(d), axis=-1)
    h = jax.nn.one_hot(ax, 3, dtype=d.dtype)
    e1 = safe_normalize(jnp.cross(d, h), jnp.asarray([1.0, 0.0, 0.0], d.dtype))
    return e1, jnp.cross(d, e1)


def cauchy(e: Array, c: Float[Array, ""] | float | None) -> Array:
    """Residual vectors e (..., 2) scaled so that |e'|^2 = c^2 log(1 + |e|^2 / c^2) (the
    Cauchy loss); e itself when c is None. Smooth at e = 0."""
    if c is None:
        return e
    x = jnp.sum(e * e, -1, keepdims=True) / c**2
    small = x < 1e-6
    xs = jnp.where(small, 1.0, x)
    ratio = jnp.where(small, 1.0 - x / 2, jnp.log1p(xs) / xs)
    return e * jnp.sqrt(ratio)


class _Problem(eqx.Module):
    """The data and the fixed parameterisation of one sequence."""

    log_len0: Array  # (G,) the start's log lengths
    uv: Array  # (T, J, 2)
    depth: Array  # (T,)
    focal: Array  # ()
    root0: Array  # (T, 2)
    d0: Array  # (T, P, 3)
    e1: Array  # (T, P, 3)
    e2: Array  # (T, P, 3)


def ancestors(tree: JointTree) -> np.ndarray:
    """(J, P) 0/1: part k lies on the path from the reference to joint j (`on_paths` over
    the parts, each part's parent the part that ends where it starts)."""
    part_of = {e: k for k, e in enumerate(tree.part_end)}
    parent = [part_of.get(tree.parents[e], -1) for e in tree.part_end]
    return on_paths(parent, [part_of.get(j, -1) for j in range(tree.n_joints)])


def _joints(tree: JointTree, options: LiftOptions, groups, y: FrameUnknowns, pb: _Problem):
    """(joints (T, J, 3), directions (T, P, 3), lengths (P,), focal) at unknowns y."""
    lengths = jnp.exp(y.border[np.asarray(groups)])
    focal = jnp.exp(y.border[-1]) if options.refine_focal else pb.focal
    ab = y.frames[:, 1:]
    d = safe_normalize(pb.d0 + ab[..., :1] * pb.e1 + ab[..., 1:] * pb.e2, pb.d0)
    root = jnp.concatenate([pb.root0 + y.frames[:, 0], pb.depth[:, None]], -1)
    # every joint is the reference plus the part vectors on its path: one product
    A = jnp.asarray(ancestors(tree), d.dtype)
    pos = root[:, None] + jnp.einsum("jk,tkc->tjc", A, lengths[None, :, None] * d)
    return pos, d, lengths, focal


def shape_rows(options: LiftOptions, d: Array, log_len: Array, log_len0: Array) -> list[Array]:
    """The frame rows (T, .) that keep the skeleton's shape: the hinge limits of the part
    directions d (T, P, 3), when `options.limits`; the log group lengths toward the start,
    when `options.length_sigma` (only from below with a prior); the prior's whitened rows,
    when `options.prior`. Border-only rows are carried by frame 0's row."""
    rows, border = [], []
    if options.limits:
        k, up, ang = (np.asarray(v) for v in zip(*options.limits))
        cos = jnp.sum(d[:, k] * d[:, up], -1)
        rows.append(jax.nn.relu(np.cos(ang) - cos) / options.limit_sigma)
    if options.length_sigma is not None:
        short = log_len - log_len0
        short = short if options.prior is None else jnp.minimum(short, 0.0)
        border.append(short / options.length_sigma)
    if options.prior is not None:
        border.append(options.prior.whiten @ (log_len - options.prior.mean))
    first = jnp.arange(d.shape[0])[:, None] == 0
    return rows + [jnp.where(first, b[None], 0.0) for b in border]


def _residuals(y: FrameUnknowns, args) -> FrameResiduals:
    tree, options, groups, pb = args
    pos, d, lengths, focal = _joints(tree, options, groups, y, pb)
    z = jnp.maximum(pos[..., 2], 1e-3)
    e = (focal * pos[..., :2] / z[..., None] - pb.uv) / options.pixel_sigma
    frame = [cauchy(e, options.robust).reshape(e.shape[0], -1)]
    frame += shape_rows(options, d, y.border[: pb.log_len0.shape[0]], pb.log_len0)
    root = pos[:, tree.root] * jnp.asarray([1.0, 1.0, 0.0], pos.dtype)
    vec = jnp.concatenate([root[:, None], lengths[None, :, None] * d], axis=1)  # (T, E, 3)
    a = options.accel_sigma
    zs = a if options.depth_accel_sigma is None else options.depth_accel_sigma
    scale = jnp.stack([a, a, zs]).astype(pos.dtype)
    acc = (vec[:-2] - 2 * vec[1:-1] + vec[2:]) / scale
    return FrameResiduals(frame=jnp.concatenate(frame, -1), window=acc)


def group_log_lengths(lengths: Array, groups) -> Array:
    """(G,) the mean log length of each length group's parts (lengths (P,), m)."""
    g, n = jnp.asarray(groups), max(groups) + 1
    total = jax.ops.segment_sum(jnp.log(lengths), g, n)
    return total / jax.ops.segment_sum(jnp.ones_like(lengths), g, n)


def lift_kernel(
    tree: JointTree,
    uv: Float[Array, "n_frames n_obs 2"],
    root_depth: Float[Array, " n_frames"],
    focal: Float[Array, ""],
    init_joints: Float[Array, "n_frames n_obs 3"],
    init_lengths: Float[Array, " n_parts"],
    options: LiftOptions,
    linear_solver=None,
) -> Lifting:
    """`refine` on one sequence (no input checks; at least 3 frames). `linear_solver`: a
    lineax solver for the steps instead of `BandedSchurCholesky` (a dense one, to compare)."""
    groups = tree.length_groups(options.symmetric)
    s, e = np.asarray(tree.part_start), np.asarray(tree.part_end)
    vec = init_joints[:, e] - init_joints[:, s]
    fallback = jnp.asarray([0.0, 0.0, 1.0], uv.dtype)
    d0 = safe_normalize(vec, fallback)
    e1, e2 = tangent_basis(d0)
    w = rays(uv, focal)
    root0 = (w[:, tree.root] * (root_depth / focal)[:, None])[:, :2]
    log_len = group_log_lengths(init_lengths, groups)
    pb = _Problem(log_len, uv, root_depth, focal, root0, d0, e1, e2)
    border = jnp.concatenate([log_len, jnp.log(focal)[None]]) if options.refine_focal else log_len
    T, P = d0.shape[:2]
    y0 = FrameUnknowns(border=border, frames=jnp.zeros((T, P + 1, 2), uv.dtype))
    args = (tree, options, groups, pb)
    solver = least_squares_solver(
        options.tol, linear_solver=linear_solver or BandedSchurCholesky(), norm=optx.rms_norm
    )
    y, status, steps = solve(_residuals, solver, y0, args, options.max_steps)
    pos, _, lengths, f = _joints(tree, options, groups, y, pb)
    z = jnp.maximum(pos[..., 2], 1e-3)
    err = f * pos[..., :2] / z[..., None] - uv
    return Lifting(
        lengths=lengths,
        joints=pos,
        focal=f,
        reprojection_rms=jnp.sqrt(jnp.mean(jnp.sum(err * err, -1))),
        steps=steps,
        status=status,
    )


def check_options(options: LiftOptions, what: str, tree: JointTree | None = None) -> None:
    """Refuse weights that are not finite and > 0 (host side), naming the option, and a
    prior that is not the tree's."""
    if options.prior is not None and tree is not None:
        n = max(tree.length_groups(True)) + 1
        if np.shape(options.prior.mean) != (n,) or np.shape(options.prior.whiten) != (n, n):
            raise ValueError(
                f"{what}: options.prior has {np.shape(options.prior.mean)} groups, the tree "
                f"{n}; build it for this tree with length_prior(tree, sex)"
            )
    for name in ("pixel_sigma", "accel_sigma", "limit_sigma", "tol"):
        v = getattr(options, name)
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{what}: options.{name} must be a finite number > 0, got {v!r}")
    for name in ("robust", "depth_accel_sigma", "length_sigma"):
        v = getattr(options, name)
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"{what}: options.{name} must be a number > 0 or None, got {v!r}")
    if options.prior is not None and not options.symmetric:
        raise ValueError(
            f"{what}: options.prior is over the length groups of symmetric lengths; "
            "set symmetric=True"
        )
    if options.max_steps < 1:
        raise ValueError(f"{what}: options.max_steps must be >= 1, got {options.max_steps}")


def _lift(tree, uv, root_depth, focal, init_joints, init_lengths, options):
    flat = uv.shape[:-3]
    n = int(np.prod(flat))
    T, J = uv.shape[-3:-1]
    out = jax.vmap(lambda a, b, c, d, e: lift_kernel(tree, a, b, c, d, e, options))(
        uv.reshape(n, T, J, 2),
        root_depth.reshape(n, T),
        jnp.broadcast_to(focal, flat).reshape(n),
        init_joints.reshape(n, T, J, 3),
        init_lengths.reshape(n, tree.n_parts),
    )
    return jax.tree.map(lambda x: x.reshape(flat + x.shape[1:]), out)


# Compiled without XLA's CPU fusion emitters (half the compile, the same answers) and kept
# exported beside the compilation cache (`_programs.compiled`).
_lift_jit = compiled(_lift)


def refine(
    tree: JointTree,
    uv: Float[ArrayLike, "*b n_frames n_obs 2"],
    root_depth: Float[ArrayLike, "*b n_frames"],
    focal: ArrayLike,
    init_joints: Float[ArrayLike, "*b n_frames n_obs 3"],
    init_lengths: Float[ArrayLike, "*b n_parts"],
    options: LiftOptions | None = None,
) -> Lifting:
    """Refine lengths and postures of one sequence or a batch (module docstring).

    Args:
        tree, uv, root_depth, focal: as for `diffbody.webb`; at least 3 frames.
        init_joints: the start (camera frame, m), e.g. `choose_reflections(...).joints`.
        init_lengths: the start's lengths (m, > 0), e.g. `choose_reflections(...).lengths`.
        options: `LiftOptions` (weights, symmetric lengths, hinge limits, robust loss,
            focal length); the defaults when None.

    Returns:
        `Lifting`: lengths, joints, focal length, reprojection RMS (px), steps and a
        a `FitStatus`; a failed solve returns its start with status FAILED, never NaN.
    """
    options = options or LiftOptions()
    uv, depth, f = check_sequence(tree, uv, root_depth, focal, "refine")
    if uv.shape[-3] < 3:
        raise ValueError(f"refine: needs at least 3 frames (accelerations), got {uv.shape[-3]}")
    joints = np.asarray(init_joints, dtype=float)
    if joints.shape != uv.shape[:-1] + (3,):
        raise ValueError(
            f"refine: init_joints must have shape {uv.shape[:-1] + (3,)}, got {joints.shape}"
        )
    if not np.all(np.isfinite(joints)):
        raise ValueError("refine: init_joints must be finite")
    lengths = np.asarray(init_lengths, dtype=float)
    if lengths.shape != uv.shape[:-3] + (tree.n_parts,):
        raise ValueError(
            f"refine: init_lengths must have shape {uv.shape[:-3] + (tree.n_parts,)}, "
            f"got {lengths.shape}"
        )
    if not np.all(np.isfinite(lengths) & (lengths > 0)):
        raise ValueError("refine: init_lengths must be finite numbers > 0 m")
    check_options(options, "refine", tree)
    dtype = jnp.zeros(()).dtype
    options = jax.tree.map(lambda v: jnp.asarray(v, dtype), options)
    return _lift_jit(
        tree,
        jnp.asarray(uv, dtype),
        jnp.asarray(depth, dtype),
        jnp.asarray(f, dtype),
        jnp.asarray(joints, dtype),
        jnp.asarray(lengths, dtype),
        options,
    )


def _pipeline(tree, uv, root_depth, focal, anchor, anchor_frame, order, options):
    from ._reflections import choose_kernel, over_sequences

    def one(a, b, c, d):
        choice = choose_kernel(tree, a, b, c, d, anchor_frame, order)
        start = choice.median_lengths  # robust to a wrong detection; directions from joints
        return choice, lift_kernel(tree, a, b, c, choice.joints, start, options)

    return over_sequences(one, tree, uv, root_depth, focal, anchor)


_pipeline_jit = compiled(_pipeline)


def lift(
    tree: JointTree,
    uv: Float[ArrayLike, "*b n_frames n_obs 2"],
    root_depth: Float[ArrayLike, "*b n_frames"],
    focal: ArrayLike,
    *,
    anchor: Int[ArrayLike, "*b n_parts"] | None = None,
    anchor_frame: int = 0,
    order: int = 2,
    options: LiftOptions | None = None,
):
    """The whole pipeline in one compiled call: reflections and Webb's lengths by
    continuity (`diffbody.choose_reflections`), then the joint refinement (`refine`) from
    its joints and robust (median) lengths. Returns (`ReflectionChoice`, `Lifting`);
    batches as `webb`."""
    from ._reflections import check_anchor

    options = options or LiftOptions()
    uv, depth, f = check_sequence(tree, uv, root_depth, focal, "lift")
    if uv.shape[-3] < 3:
        raise ValueError(f"lift: needs at least 3 frames (accelerations), got {uv.shape[-3]}")
    a = check_anchor(tree, anchor, uv.shape, anchor_frame, order, "lift")
    check_options(options, "lift", tree)
    dtype = jnp.zeros(()).dtype
    options = jax.tree.map(lambda v: jnp.asarray(v, dtype), options)
    return _pipeline_jit(
        tree,
        jnp.asarray(uv, dtype),
        jnp.asarray(depth, dtype),
        jnp.asarray(f, dtype),
        jnp.asarray(a, jnp.int32),
        anchor_frame % uv.shape[-3],
        order,
        options,
    )
