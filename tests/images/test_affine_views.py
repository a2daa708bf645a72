"""Cameras of unknown placement (scaled orthography): exact shape from exact views, the
scale from the prior as its minimiser, and bad input refused."""

import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody.images._affine_views import lift_views_uncalibrated
from diffbody.images._joint_tree import default_joint_tree
from diffbody.images._length_prior import length_prior


@pytest.fixture(scope="module")
def tree():
    return default_joint_tree()


@pytest.fixture(scope="module")
def seen(tree, male50):
    """A walk of 20 frames seen in exact scaled orthography by three views of different
    rotations, scales (px per m) and shifts: (world joints, image points, scales)."""
    world = np.asarray(db.walking_motion(male50, tree, 20))
    rng = np.random.default_rng(0)
    scales = np.asarray([300.0, 420.0, 250.0])
    uv = []
    for s in scales:
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        uv.append(s * world @ q[:2].T + rng.normal(size=2) * 50)
    return world, np.stack(uv), scales


def _procrustes(X, Y):
    """X (n, 3) brought onto Y by a rotation or reflection and a scale, about centroids."""
    X, Y = X - X.mean(0), Y - Y.mean(0)
    U, s, Vt = np.linalg.svd(X.T @ Y)
    return s.sum() / (X**2).sum() * X @ U @ Vt


def test_exact_views_give_the_shape(tree, seen):
    """Exact scaled-orthographic views: every part's length is the truth's times one common
    factor (the prior's scale), the joints are the truth's up to a rotation, a mirror and
    that scale, and the views' scales stand in the truth's ratios."""
    world, uv, scales = seen
    out = lift_views_uncalibrated(tree, uv, length_prior(tree, "male"))
    s, e = list(tree.part_start), list(tree.part_end)
    ratio = np.asarray(out.lengths) / np.linalg.norm(world[0, e] - world[0, s], axis=-1)
    np.testing.assert_allclose(ratio, ratio.mean(), rtol=1e-6)
    assert abs(ratio.mean() - 1) < 0.05  # the median man, by the prior of the male survey
    X, Y = np.asarray(out.joints).reshape(-1, 3), world.reshape(-1, 3)
    np.testing.assert_allclose(_procrustes(X, Y), Y - Y.mean(0), atol=1e-6)
    v = np.asarray(out.view_scales)
    np.testing.assert_allclose(v / v[0], scales / scales[0], rtol=1e-6)
    assert float(out.residual_rms) < 1e-6


def test_the_scale_is_the_priors_best(tree, seen):
    """The prior's whitened distance of c L is least at the answer's scale."""
    world, uv, _ = seen
    prior = length_prior(tree, "male")
    out = lift_views_uncalibrated(tree, uv, prior)
    groups = np.asarray(tree.length_groups(True))
    first = [int(np.flatnonzero(groups == g)[0]) for g in range(groups.max() + 1)]
    log_len = np.log(np.asarray(out.lengths)[first])
    W, mean = np.asarray(prior.whiten), np.asarray(prior.mean)
    cost = lambda d: float(np.sum((W @ (log_len + d - mean)) ** 2))  # noqa: E731
    assert cost(0.0) < cost(0.01) and cost(0.0) < cost(-0.01)


def test_bad_input_is_refused(tree, seen):
    _, uv, _ = seen
    prior = length_prior(tree, "male")
    with pytest.raises(ValueError, match="V >= 2 views"):
        lift_views_uncalibrated(tree, uv[:1], prior)
    bad = uv.copy()
    bad[2, 5, 1, 0] = np.nan
    with pytest.raises(ValueError, match="joint 'left_hip' in frame 5 of view 2"):
        lift_views_uncalibrated(tree, bad, prior)
    small = length_prior(db.images.JointTree.from_parents(["center_hip", "left_hip"], [-1, 0]))
    with pytest.raises(ValueError, match="build it for this tree"):
        lift_views_uncalibrated(tree, jnp.asarray(uv), small)


def test_derivatives(tree, seen):
    """d lengths / d uv through the SVD and the eigen-decomposition: forward and reverse
    mode agree with central differences (noisy views, distinct singular values)."""
    import jax

    from diffbody.images._affine_views import affine_kernel

    _, uv, _ = seen
    uv = jnp.asarray(uv[:, :3] + np.random.default_rng(1).normal(size=uv[:, :3].shape))
    prior = length_prior(tree, "male")
    f = jax.jit(lambda u: affine_kernel(tree, u, prior).lengths[:4])
    Jf, Jr = np.asarray(jax.jacfwd(f)(uv)), np.asarray(jax.jacrev(f)(uv))
    np.testing.assert_allclose(Jf, Jr, atol=1e-10)
    rng = np.random.default_rng(2)
    for _ in range(3):
        d = rng.normal(size=uv.shape)
        h = 1e-4
        fd = (np.asarray(f(uv + h * d)) - np.asarray(f(uv - h * d))) / (2 * h)
        np.testing.assert_allclose(np.tensordot(Jf, d, axes=4), fd, rtol=1e-5, atol=1e-9)


def test_views_that_cannot_fix_the_depth_fail(tree, seen):
    """Three views from one direction (the same rotation, 1 px apart): nothing pins the
    depth, and the answer says FAILED rather than a stretched figure."""
    _, uv, _ = seen
    same = np.stack([uv[0]] * 3) + np.random.default_rng(5).normal(size=(3,) + uv.shape[1:])
    out = lift_views_uncalibrated(tree, same, length_prior(tree, "male"))
    assert int(out.status) == db.FitStatus.FAILED
