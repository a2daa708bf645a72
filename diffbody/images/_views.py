"""Lengths and 3D postures from several calibrated cameras (beyond seed 003; docs/design.md,
section 8): `triangulate` and `lift_views`.

Seen by two or more cameras of known placement and focal length (`Pinhole`), a joint lies
where the rays through its image points meet: `triangulate` takes the point nearest to all
of them in the least-squares sense, sum over views of |(I - d d^T)(X - c)|^2 with c a
camera's centre and d its unit ray, one 3x3 solve per joint and frame. No reference depth
and no reflection is needed, so none of the single view's ambiguities remain.

`lift_views` then fits the rigid skeleton to every view at once, the same least-squares
problem as the one-camera refinement (`refine`) with the world frame's reference joint free
in all three coordinates: unknowns, the log length of every length group (shared by all
frames) and per frame the reference joint's position and each part's direction in the plane
tangent to its start; residuals, every view's reprojection (px) through the Cauchy loss,
the accelerations of the reference and of every part (m per frame^2, the same in every
direction: no axis is a depth here), the log lengths toward the start, the hinge limits.
It starts from the triangulated joints, each part's length the median over the frames of
its triangulated length. The reference joint's three coordinates are two of
`BandedSchurCholesky`'s per-frame entities of two unknowns, (x, y) and (z, pad); the pad
unknown has a unit row of its own that holds it at zero.

A view that does not see a joint gives NaN for its image point: triangulation uses the views
that see it (a joint seen by fewer than two is NaN there, and starts from its nearest frame
that is seen twice), and the fit has no reprojection row for it: the rigid parts and the
accelerations carry a joint through frames where no view sees it.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float, Int

from .._programs import compiled
from .._rotations import safe_normalize
from .._solver import least_squares_solver, solve
from ._banded import BandedSchurCholesky, FrameResiduals, FrameUnknowns
from ._joint_tree import JointTree
from ._lifting import (
    LiftOptions,
    ancestors,
    cauchy,
    check_options,
    group_log_lengths,
    shape_rows,
    tangent_basis,
)
from ._pinhole import Pinhole, check_focal


class ViewsLifting(eqx.Module):
    """A sequence lifted from several calibrated views (world frame); leading batch axes
    when batched."""

    lengths: Float[Array, "*b n_parts"]  # m
    joints: Float[Array, "*b n_frames n_obs 3"]  # m, world
    reprojection_rms: Float[Array, "*b"]  # px, over every view, joint and frame
    steps: Int[Array, "*b"]  # Levenberg-Marquardt steps taken
    status: Int[Array, "*b"]  # a FitStatus


def stack_cameras(cameras: Sequence[Pinhole] | Pinhole) -> Pinhole:
    """Cameras as one `Pinhole` with a leading view axis (a stacked one as it is)."""
    if isinstance(cameras, Pinhole):
        return cameras
    cameras = list(cameras)
    return jax.tree.map(lambda *a: jnp.stack([jnp.asarray(x, float) for x in a]), *cameras)


def world_rays(cameras: Pinhole, uv: Float[Array, "V ... 2"]) -> Float[Array, "V ... 3"]:
    """Unit world directions of the rays through image points uv (V, ..., 2) px of the V
    stacked cameras."""
    V = uv.shape[0]
    lead = (V,) + (1,) * (uv.ndim - 2)
    f = jnp.broadcast_to(cameras.focal.reshape(lead), uv.shape[:-1])
    d_camera = jnp.concatenate([uv, f[..., None]], axis=-1)
    R = cameras.R_camera_world.reshape(lead + (3, 3))
    d_world = jnp.einsum("v...ab,v...a->v...b", R, d_camera)  # R^T d
    return safe_normalize(d_world, jnp.asarray([0.0, 0.0, 1.0], uv.dtype))


def triangulate(
    cameras: Sequence[Pinhole] | Pinhole, uv: Float[ArrayLike, "V *b 2"]
) -> Float[Array, "*b 3"]:
    """World points (..., 3) m nearest in the least-squares sense to the rays of their
    image points uv (V, ..., 2) px in V >= 2 cameras (a list, or stacked: `stack_cameras`):
    the solve of sum_v (I - d_v d_v^T) X = sum_v (I - d_v d_v^T) c_v over the views that
    see the point (module docstring). An image point of NaN is a point that view does not
    see; a point seen by fewer than two views is NaN. Rays that are all parallel leave X
    along them undetermined: the cameras must see from apart. No input checks
    (`lift_views` has them); differentiable in uv and the cameras."""
    cameras = stack_cameras(cameras)
    uv = jnp.asarray(uv)
    seen = jnp.all(jnp.isfinite(uv), axis=-1)  # (V, ...)
    d = world_rays(cameras, jnp.where(seen[..., None], uv, 0.0))
    P = jnp.eye(3, dtype=uv.dtype) - d[..., :, None] * d[..., None, :]  # (V, ..., 3, 3)
    P = jnp.where(seen[..., None, None], P, 0.0)
    lead = (uv.shape[0],) + (1,) * (uv.ndim - 2)
    c = cameras.p_world_camera.reshape(lead + (3,)).astype(uv.dtype)
    twice = jnp.sum(seen, axis=0) >= 2
    A = jnp.where(twice[..., None, None], jnp.sum(P, axis=0), jnp.eye(3, dtype=uv.dtype))
    b = jnp.sum(jnp.einsum("v...ab,v...b->v...a", P, jnp.broadcast_to(c, d.shape)), axis=0)
    X = jnp.linalg.solve(A, b[..., None])[..., 0]
    return jnp.where(twice[..., None], X, jnp.nan)


def nearest_seen(X: Float[Array, "T J 3"]) -> Float[Array, "T J 3"]:
    """Each joint's NaN frames (T, J, 3) filled from its nearest frame that is not NaN
    (ties: the earlier); a joint NaN in every frame stays NaN."""
    T = X.shape[0]
    ok = jnp.all(jnp.isfinite(X), axis=-1)  # (T, J)
    t = jnp.arange(T)[:, None]
    before = jax.lax.cummax(jnp.where(ok, t, -1), axis=0)
    after = jax.lax.cummin(jnp.where(ok, t, T), axis=0, reverse=True)
    use_before = (before >= 0) & ((after >= T) | (t - before <= after - t))
    src = jnp.clip(jnp.where(use_before, before, after), 0, T - 1)
    return jnp.take_along_axis(X, src[..., None], axis=0)


class _Problem(eqx.Module):
    """One sequence's data and fixed parameterisation."""

    log_len0: Array  # (G,)
    uv: Array  # (V, T, J, 2)
    root0: Array  # (T, 3)
    d0: Array  # (T, P, 3)
    e1: Array
    e2: Array


def _joints(tree: JointTree, groups, y: FrameUnknowns, pb: _Problem):
    """(joints (T, J, 3) world, directions (T, P, 3), lengths (P,)) at unknowns y."""
    lengths = jnp.exp(y.border[np.asarray(groups)])
    ab = y.frames[:, 2:]
    d = safe_normalize(pb.d0 + ab[..., :1] * pb.e1 + ab[..., 1:] * pb.e2, pb.d0)
    root = pb.root0 + jnp.concatenate([y.frames[:, 0], y.frames[:, 1, :1]], -1)
    A = jnp.asarray(ancestors(tree), d.dtype)
    pos = root[:, None] + jnp.einsum("jk,tkc->tjc", A, lengths[None, :, None] * d)
    return pos, d, lengths


def reprojection(cameras: Pinhole, pos: Array, uv: Array) -> Array:
    """(V, T, J, 2) px: where the V cameras see world points pos (T, J, 3), less uv; 0
    where uv is NaN (not seen)."""
    R, c = cameras.R_camera_world, cameras.p_world_camera
    p = jnp.einsum("vab,tjb->vtja", R, pos) - jnp.einsum("vab,vb->va", R, c)[:, None, None]
    z = jnp.maximum(p[..., 2], 1e-3)
    seen = jnp.isfinite(uv)
    return jnp.where(
        seen,
        cameras.focal[:, None, None, None] * p[..., :2] / z[..., None] - jnp.where(seen, uv, 0.0),
        0.0,
    )


def _residuals(y: FrameUnknowns, args) -> FrameResiduals:
    tree, options, groups, cameras, pb = args
    pos, d, lengths = _joints(tree, groups, y, pb)
    e = reprojection(cameras, pos, pb.uv) / options.pixel_sigma  # (V, T, J, 2)
    e = jnp.moveaxis(cauchy(e, options.robust), 0, 1)
    frame = [e.reshape(e.shape[0], -1), y.frames[:, 1, 1:]]  # the pad unknown held at zero
    frame += shape_rows(options, d, y.border, pb.log_len0)
    root = pos[:, tree.root]
    zero = jnp.zeros_like(root[:, :1])
    vec = jnp.concatenate(
        [
            jnp.concatenate([root[:, :2], zero], -1)[:, None],
            jnp.concatenate([zero, zero, root[:, 2:]], -1)[:, None],
            lengths[None, :, None] * d,
        ],
        axis=1,
    )  # (T, P + 2, 3): each entity's own coordinates
    acc = (vec[:-2] - 2 * vec[1:-1] + vec[2:]) / options.accel_sigma
    return FrameResiduals(frame=jnp.concatenate(frame, -1), window=acc)


def views_kernel(
    tree: JointTree,
    cameras: Pinhole,
    uv: Float[Array, "V n_frames n_obs 2"],
    options: LiftOptions,
) -> ViewsLifting:
    """`lift_views` on one sequence (no input checks; at least 3 frames, V >= 2)."""
    groups = tree.length_groups(options.symmetric)
    seen_twice = triangulate(cameras, uv)  # (T, J, 3), NaN where fewer than two views see
    s, e = np.asarray(tree.part_start), np.asarray(tree.part_end)
    length0 = jnp.nanmedian(jnp.linalg.norm(seen_twice[:, e] - seen_twice[:, s], axis=-1), 0)
    joints = nearest_seen(seen_twice)
    vec = joints[:, e] - joints[:, s]
    d0 = safe_normalize(vec, jnp.asarray([0.0, 0.0, 1.0], uv.dtype))
    e1, e2 = tangent_basis(d0)
    log_len = group_log_lengths(length0, groups)
    pb = _Problem(log_len, uv, joints[:, tree.root], d0, e1, e2)
    T, P = d0.shape[:2]
    y0 = FrameUnknowns(border=log_len, frames=jnp.zeros((T, P + 2, 2), uv.dtype))
    args = (tree, options, groups, cameras, pb)
    solver = least_squares_solver(
        options.tol, linear_solver=BandedSchurCholesky(), norm=optx.rms_norm
    )
    y, status, steps = solve(_residuals, solver, y0, args, options.max_steps)
    pos, _, lengths = _joints(tree, groups, y, pb)
    err = reprojection(cameras, pos, uv)
    n_seen = jnp.sum(jnp.all(jnp.isfinite(uv), -1))
    return ViewsLifting(
        lengths=lengths,
        joints=pos,
        reprojection_rms=jnp.sqrt(jnp.sum(err * err) / jnp.maximum(n_seen, 1)),
        steps=steps,
        status=status,
    )


def _views(tree, cameras, uv, options):
    flat = uv.shape[:-4]
    n = int(np.prod(flat))
    V, T, J = uv.shape[-4:-1]
    out = jax.vmap(lambda a: views_kernel(tree, cameras, a, options))(uv.reshape(n, V, T, J, 2))
    return jax.tree.map(lambda x: x.reshape(flat + x.shape[1:]), out)


_views_jit = compiled(_views)  # as the one-camera lifting's (`_lifting`)


def check_views(tree: JointTree, cameras: Pinhole, uv, what: str) -> np.ndarray:
    """Host checks of cameras (V stacked) and image points (..., V, T, J, 2): shapes,
    finite values, focal lengths > 0, rotations that are rotations, cameras apart. Errors
    name the entry and the fix."""
    uv = np.asarray(uv, dtype=float)
    f = np.asarray(cameras.focal, dtype=float)
    V = f.shape[0] if f.ndim == 1 else 0
    if V < 2 or np.shape(cameras.R_camera_world) != (V, 3, 3):
        raise ValueError(
            f"{what}: needs two or more cameras (a list of Pinhole, or one stacked with a "
            f"leading view axis), got focal lengths of shape {f.shape}"
        )
    check_focal(f)
    R = np.asarray(cameras.R_camera_world, dtype=float)
    off = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(-1, -2))
    if not np.all(off < 1e-4):
        raise ValueError(
            f"{what}: camera {int(np.argmax(off))}'s R_camera_world is not a rotation "
            "(R R^T != I); build cameras with look_at or camera_around"
        )
    c = np.asarray(cameras.p_world_camera, dtype=float)
    if np.linalg.norm(c - c[0], axis=-1).max() < 1e-6:
        raise ValueError(
            f"{what}: every camera has its centre at the same place; triangulation needs "
            "cameras that see from apart"
        )
    if uv.ndim < 4 or uv.shape[-1] != 2 or uv.shape[-2] != tree.n_joints or uv.shape[-4] != V:
        raise ValueError(
            f"{what}: image points must have shape (..., {V} views, n_frames, "
            f"{tree.n_joints} joints, 2), got {uv.shape}"
        )
    if uv.shape[-3] < 3:
        raise ValueError(f"{what}: needs at least 3 frames (accelerations), got {uv.shape[-3]}")
    bad = np.argwhere(np.isinf(uv) | (np.isnan(uv) != np.isnan(uv[..., ::-1])))
    if len(bad):
        i = tuple(int(x) for x in bad[0])
        seq = f" of sequence {i[:-4]}" if len(i) > 4 else ""
        raise ValueError(
            f"{what}: the image point of joint {tree.names[i[-2]]!r} in frame {i[-3]} of view "
            f"{i[-4]}{seq} is {uv[i[:-1]].tolist()}; give a finite (u, v) in px, or NaN for "
            "both where that view does not see the joint"
        )
    # A part's start: a frame where two views see both its ends.
    twice = np.sum(np.all(np.isfinite(uv), -1), axis=-3) >= 2  # (..., T, J)
    both = twice[..., list(tree.part_start)] & twice[..., list(tree.part_end)]
    never = np.argwhere(~np.any(both, axis=-2))  # (..., P)
    if len(never):
        i = tuple(int(x) for x in never[0])
        seq = f" in sequence {i[:-1]}" if len(i) > 1 else ""
        raise ValueError(
            f"{what}: no frame{seq} has both ends of part {tree.part_names[i[-1]]!r} seen by "
            "two or more views; give such a frame (its length starts there)"
        )
    return uv


def lift_views(
    tree: JointTree,
    cameras: Sequence[Pinhole] | Pinhole,
    uv: Float[ArrayLike, "*b V n_frames n_obs 2"],
    options: LiftOptions | None = None,
) -> ViewsLifting:
    """Lengths and 3D joints (world frame) of a sequence seen by several calibrated
    cameras: triangulated, then the rigid skeleton fitted to every view at once (module
    docstring). One compiled program per (views, frames, joints) shape and batch shape.

    Args:
        tree: the observed joints (`default_joint_tree`, `read_joint_tree`).
        cameras: two or more `Pinhole` cameras (`look_at`, `camera_around`), or one with a
            leading view axis.
        uv: image points (..., V, T, J, 2) px from each camera's principal point, v down;
            NaN (both coordinates) where a view does not see a joint; leading axes are a
            batch of sequences seen by the same cameras; T >= 3. Every part needs a frame
            where two views see both its ends.
        options: `LiftOptions` (pixel noise, accelerations, robust loss, symmetric lengths,
            hinge limits, steps); `depth_accel_sigma` does not apply (the accelerations are
            the same in every direction) and `refine_focal` is refused (the cameras are
            calibrated).

    Returns:
        `ViewsLifting`: lengths, joints, reprojection RMS (px), steps and a `FitStatus`; a
        solve that fails returns the triangulated start with status FAILED, never NaN.
    """
    options = options or LiftOptions()
    cameras = stack_cameras(cameras)
    uv = check_views(tree, cameras, uv, "lift_views")
    check_options(options, "lift_views", tree)
    if options.refine_focal:
        raise ValueError(
            "lift_views: options.refine_focal must be False; the cameras are calibrated "
            "(their focal lengths are given)"
        )
    dtype = jnp.zeros(()).dtype
    options = jax.tree.map(lambda v: jnp.asarray(v, dtype), options)
    cameras = jax.tree.map(lambda v: jax.device_put(np.asarray(v, dtype)), cameras)
    return _views_jit(tree, cameras, jax.device_put(uv.astype(dtype)), options)
