"""Several calibrated cameras: triangulation against an independent linear method (DLT), its
derivatives, exact recovery without noise, the accuracy the views give under pixel noise,
and bad input refused."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffbody._statuses import FitStatus
from diffbody.images._joint_tree import default_joint_tree
from diffbody.images._lifting import LiftOptions
from diffbody.images._motions import walking_motion
from diffbody.images._pinhole import camera_around, project, to_camera
from diffbody.images._views import lift_views, nearest_seen, stack_cameras, triangulate

F = 1000.0
AZIMUTHS = (20.0, 110.0)  # two cameras 90 degrees apart
FRAMES = 24


@pytest.fixture(scope="module")
def tree():
    return default_joint_tree()


@pytest.fixture(scope="module")
def walk(tree):
    """The default body's walk (world, m) and two cameras 3 m away that see it."""
    import diffbody as db

    world = np.asarray(walking_motion(db.load_body(), tree, FRAMES))
    centre = world[:, tree.root].mean(0)
    cams = [camera_around([centre[0], centre[1], 1.0], 3.0, az, 1.2, F) for az in AZIMUTHS]
    return world, cams


def _images(cams, world, noise=0.0, seed=0):
    uv = np.stack([np.asarray(project(to_camera(c, world), c.focal)) for c in cams])
    return uv + noise * np.random.default_rng(seed).normal(size=uv.shape)


def _part_lengths(tree, joints):
    s, e = list(tree.part_start), list(tree.part_end)
    return np.linalg.norm(joints[..., e, :] - joints[..., s, :], axis=-1)


def _dlt(cams, uv):
    """The textbook direct linear transform: the null vector of the 2V x 4 rows
    u P_3 - P_1, v P_3 - P_2 of each camera's projection matrix P = K [R | -R c]."""
    rows = []
    for cam, (u, v) in zip(cams, uv):
        R, c, f = (
            np.asarray(a, float) for a in (cam.R_camera_world, cam.p_world_camera, cam.focal)
        )
        P = np.diag([f, f, 1.0]) @ np.hstack([R, -R @ c[:, None]])
        rows += [u * P[2] - P[0], v * P[2] - P[1]]
    X = np.linalg.svd(np.asarray(rows))[2][-1]
    return X[:3] / X[3]


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(-0.8, 0.8), min_size=3, max_size=3),
    st.floats(0.0, 2.0),
    st.floats(0.5, 2.5),
)
def test_triangulation_matches_the_dlt(xyz, noise, spread):
    """With noise the two methods minimise different errors and agree only to first order
    in it; without noise both give the point. A reference: the DLT by SVD, in NumPy."""
    point = np.asarray(xyz) + [0.0, 0.0, 1.0]
    azimuths = (0.0, 40.0 * spread, -60.0)
    cams = [camera_around([0.0, 0.0, 1.0], 3.0, az, 1.2, F) for az in azimuths]
    uv = _images(cams, point[None])[:, 0]
    X = np.asarray(triangulate(stack_cameras(cams), uv))
    np.testing.assert_allclose(X, point, atol=1e-9)
    np.testing.assert_allclose(X, _dlt(cams, uv), atol=1e-9)
    noisy = uv + noise * np.random.default_rng(1).normal(size=uv.shape)
    X = np.asarray(triangulate(stack_cameras(cams), noisy))
    np.testing.assert_allclose(X, _dlt(cams, noisy), atol=1e-3 * (1 + noise))


def test_triangulation_moves_with_the_world():
    """Shifting the cameras and the point together shifts the answer by as much."""
    cams = [camera_around([0.0, 0.0, 1.0], 3.0, az, 1.2, F) for az in (10.0, 95.0)]
    uv = _images(cams, np.asarray([[0.1, -0.2, 1.3]]), noise=1.0)[:, 0]
    shift = np.asarray([5.0, -3.0, 0.5])
    stacked = stack_cameras(cams)
    moved = type(stacked)(stacked.focal, stacked.R_camera_world, stacked.p_world_camera + shift)
    a = np.asarray(triangulate(stacked, uv))
    b = np.asarray(triangulate(moved, uv))
    np.testing.assert_allclose(b - a, shift, atol=1e-9)


def test_triangulation_derivatives():
    """d X / d uv: forward and reverse mode agree with central differences."""
    cams = [camera_around([0.0, 0.0, 1.0], 3.0, az, 1.2, F) for az in (0.0, 70.0, 150.0)]
    uv = jnp.asarray(_images(cams, np.asarray([[0.2, 0.1, 1.1]]), noise=0.5)[:, 0])
    f = jax.jit(lambda u: triangulate(cams, u))
    Jf, Jr = jax.jacfwd(f)(uv), jax.jacrev(f)(uv)
    h = 1e-4
    fd = np.zeros((3,) + uv.shape)
    for i in np.ndindex(uv.shape):
        e = np.zeros(uv.shape)
        e[i] = h
        fd[(slice(None),) + i] = (np.asarray(f(uv + e)) - np.asarray(f(uv - e))) / (2 * h)
    np.testing.assert_allclose(Jf, Jr, atol=1e-12)
    np.testing.assert_allclose(Jf, fd, atol=1e-8)


def test_exact_images_give_the_skeleton(tree, walk):
    """Without noise, and with the accelerations' prior turned off (the walk does
    accelerate), the skeleton comes back exactly: lengths, joints, no reprojection. (A
    batch of two, the walk and the walk 0.2 m to the side: the noise test's program.)"""
    world, cams = walk
    worlds = np.stack([world, world + [0.0, 0.2, 0.0]])
    exact = LiftOptions(accel_sigma=1e3)  # no acceleration prior; a weight, not a new program
    out = lift_views(tree, cams, np.stack([_images(cams, w) for w in worlds]), exact)
    assert np.all(np.asarray(out.status) != FitStatus.FAILED)
    np.testing.assert_allclose(
        out.lengths, np.stack([_part_lengths(tree, world[0])] * 2), atol=1e-7
    )
    np.testing.assert_allclose(out.joints, worlds, atol=1e-7)
    assert np.all(np.asarray(out.reprojection_rms) < 1e-6)


def test_two_views_under_noise(tree, walk):
    """1 px of noise, two views 90 degrees apart, a walk of 24 frames: lengths within 1 %
    and joints within 10 mm (the goal's figures); the rigid fit is closer than the
    triangulation it starts from; a batch of two gives each sequence's own answer."""
    world, cams = walk
    uv = np.stack([_images(cams, world, 1.0, seed) for seed in (0, 1)])
    out = lift_views(tree, cams, uv)
    truth = _part_lengths(tree, world[0])
    for k in range(2):
        rel = np.abs(np.asarray(out.lengths[k]) / truth - 1).mean()
        mpjpe = np.linalg.norm(np.asarray(out.joints[k]) - world, axis=-1).mean()
        tri = np.linalg.norm(np.asarray(triangulate(stack_cameras(cams), uv[k])) - world, axis=-1)
        assert rel < 0.01 and mpjpe < 0.010, (k, rel, mpjpe)
        assert mpjpe < tri.mean()
        assert 0.5 < float(out.reprojection_rms[k]) < 2.0  # px: about the noise's sqrt(2)
    swapped = lift_views(tree, cams, uv[::-1])  # the same program, the rows swapped
    np.testing.assert_allclose(swapped.lengths[0], out.lengths[1], atol=1e-9)


def test_bad_input_is_refused(tree, walk):
    world, cams = walk
    uv = _images(cams, world)
    with pytest.raises(ValueError, match="two or more cameras"):
        lift_views(tree, cams[:1], uv[:1])
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2 views"):
        lift_views(tree, cams, uv[:, :, :5])
    bad = uv.copy()
    bad[1, 7, 3, 0] = np.nan
    with pytest.raises(ValueError, match="joint 'left_ankle' in frame 7 of view 1"):
        lift_views(tree, cams, bad)
    with pytest.raises(ValueError, match="at least 3 frames"):
        lift_views(tree, cams, uv[:, :2])
    with pytest.raises(ValueError, match="refine_focal must be False"):
        lift_views(tree, cams, uv, LiftOptions(refine_focal=True))
    with pytest.raises(ValueError, match="same place"):
        lift_views(tree, [cams[0], cams[0]], uv)
    with pytest.raises(ValueError, match="pixel_sigma"):
        lift_views(tree, cams, uv, LiftOptions(pixel_sigma=0.0))


def test_a_view_that_does_not_see_a_point_is_left_out():
    """NaN in one of three views: the point the other two give; in two of three: NaN."""
    cams = [camera_around([0.0, 0.0, 1.0], 3.0, az, 1.2, F) for az in (0.0, 70.0, 150.0)]
    uv = _images(cams, np.asarray([[0.2, 0.1, 1.1]]), noise=0.7)[:, 0]
    hidden = uv.copy()
    hidden[1] = np.nan
    np.testing.assert_allclose(
        triangulate(cams, hidden), triangulate([cams[0], cams[2]], uv[[0, 2]]), atol=1e-12
    )
    # derivatives stay finite beside a hidden view, and none flows from it
    J = np.asarray(jax.jacfwd(lambda u: triangulate(cams, u))(jnp.asarray(hidden)))
    assert np.all(np.isfinite(J)) and not np.any(J[:, 1])
    hidden[0] = np.nan
    assert np.all(np.isnan(np.asarray(triangulate(cams, hidden))))


def test_nearest_seen_fills_from_the_nearest_frame():
    X = np.arange(6.0)[:, None, None] * np.ones((6, 2, 3))
    X[[0, 2, 3], 0] = np.nan  # joint 0 seen in frames 1, 4, 5
    X[:, 1] = np.nan  # joint 1 never
    got = np.asarray(nearest_seen(jnp.asarray(X)))
    np.testing.assert_array_equal(got[:, 0, 0], [1, 1, 1, 4, 4, 5])  # frame 2 ties: the earlier
    assert np.all(np.isnan(got[:, 1]))


def test_missing_detections(tree, walk):
    """Three views, a fifth of the image points missing at random and the left wrist seen
    by no view for four frames, 1 px of noise: lengths within 1 %, joints within 10 mm, the
    hidden wrist within 3 cm where no view sees it."""
    world, cams2 = walk
    centre = world[:, tree.root].mean(0)
    cams = cams2 + [camera_around([centre[0], centre[1], 1.0], 3.0, 200.0, 1.2, F)]
    uv = _images(cams, world, 1.0, seed=3)
    rng = np.random.default_rng(4)
    uv[rng.random(uv.shape[:-1]) < 0.2] = np.nan
    wrist = tree.index("left_wrist")
    uv[:, 10:14, wrist] = np.nan
    out = lift_views(tree, cams, uv)
    rel = np.abs(np.asarray(out.lengths) / _part_lengths(tree, world[0]) - 1).mean()
    error = np.linalg.norm(np.asarray(out.joints) - world, axis=-1)
    assert rel < 0.01 and error.mean() < 0.010, (rel, error.mean())
    assert error[10:14, wrist].max() < 0.03, error[10:14, wrist]
    assert int(out.status) != FitStatus.FAILED and np.isfinite(float(out.reprojection_rms))
    blind = uv.copy()
    blind[:, :, wrist] = np.nan  # the left forearm's far end never seen
    with pytest.raises(ValueError, match="left_elbow->left_wrist"):
        lift_views(tree, cams, blind)
