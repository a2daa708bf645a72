"""Beyond seed 003: reflections by continuity, the joint least-squares refinement (against a
dense solver, its derivatives, under noise and wrong detections), and the semi-real walk."""

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

from diffbody._statuses import FitStatus
from diffbody.images._banded import BandedSchurCholesky, FrameResiduals, FrameUnknowns
from diffbody.images._joint_centres import NAMES, joint_centres_from_markers, load_walk_joints
from diffbody.images._joint_tree import default_joint_tree
from diffbody.images._length_prior import length_prior
from diffbody.images._lifting import LiftOptions, lift
from diffbody.images._motions import walking_motion
from diffbody.images._pinhole import camera_around, image_sequence, project
from diffbody.images._reflections import choose_reflections
from diffbody.images._webb import NEAR, true_reflections

F = 1000.0


@pytest.fixture(scope="module")
def tree():
    return default_joint_tree()


def _sweeping(tree, n_frames: int = 120):
    """Camera-frame joints of the default tree's proportions in which every part swings
    smoothly through the view perpendicular to its ray, back and forth: part k keeps a
    lateral direction u_k and tilts in depth by sin(2 pi t / P_k + phase_k) rad, P_k
    50-100 frames."""
    rng = np.random.default_rng(7)
    lengths = np.array(
        [0.09, 0.09, 0.62, 0.41, 0.41, 0.24, 0.23, 0.23, 0.42, 0.42, 0.28, 0.28, 0.27, 0.27]
    )
    t = np.arange(n_frames)[:, None]
    period = rng.uniform(50, 100, tree.n_parts)
    phase = rng.uniform(0, 2 * np.pi, tree.n_parts)
    tilt = np.sin(2 * np.pi * t / period + phase)  # (T, P)
    lateral = rng.normal(size=(tree.n_parts, 2))
    lateral /= np.linalg.norm(lateral, axis=1, keepdims=True)
    d = np.concatenate([np.cos(tilt)[..., None] * lateral[None], np.sin(tilt)[..., None]], axis=-1)
    joints = np.zeros((n_frames, tree.n_joints, 3))
    joints[:, tree.root] = [0.05, 0.1, 3.0]
    for k in range(tree.n_parts):
        joints[:, tree.part_end[k]] = joints[:, tree.part_start[k]] + lengths[k] * d[:, k]
    return joints, lengths


def test_continuity_tracks_the_reflections(tree):
    """Smooth motion through the perpendicular views: given the reflections of the first
    frame, continuity (least acceleration) finds most later ones where the two candidates
    differ by a centimetre (a crossing sampled far from its perpendicular view can be
    taken for a turn back, and the mirror image after it is nearly as smooth), and the
    lengths come out right; least velocity does worse."""
    joints, lengths = _sweeping(tree)
    truth = np.asarray(true_reflections(tree, joints))
    uv = project(joints, F)
    out = choose_reflections(tree, uv, joints[:, tree.root, 2], F, anchor=truth[0])
    seen = np.asarray(out.separation) > 0.01
    assert seen.mean() > 0.5
    match = np.asarray(out.reflections) == truth
    assert match[seen].mean() > 0.9
    np.testing.assert_array_less(np.abs(np.asarray(out.lengths) / lengths - 1), 1e-3)
    np.testing.assert_array_less(np.abs(np.asarray(out.median_lengths) / lengths - 1), 1e-2)
    # by velocity (order 1) the least motion is often to turn back at the perpendicular
    slow = choose_reflections(tree, uv, joints[:, tree.root, 2], F, anchor=truth[0], order=1)
    assert (np.asarray(slow.reflections) == truth)[seen].mean() < match[seen].mean()


@pytest.fixture(scope="module")
def noisy_walk(tree, male50):
    """The walking body, 60 frames at 3 m, 1 px noise (the command line's example's shape,
    so the compiled pipeline is shared)."""
    world = walking_motion(male50, tree, 60)
    seq = image_sequence(
        tree, camera_around([0.0, 0.0, 1.0], 3.0, 10.0, 1.2, F), world, 1.0, jax.random.PRNGKey(1)
    )
    vec = np.asarray(world[0, list(tree.part_end)] - world[0, list(tree.part_start)])
    return seq, np.linalg.norm(vec, axis=-1)


def _errors(out, seq, lengths):
    rel = np.abs(np.asarray(out.lengths) / lengths - 1).mean()
    mpjpe = np.linalg.norm(np.asarray(out.joints) - np.asarray(seq.joints), axis=-1).mean()
    return rel, mpjpe


def test_refinement_beats_webb_under_noise(tree, noisy_walk):
    seq, lengths = noisy_walk
    anchor = np.asarray(true_reflections(tree, seq.joints))[0]
    choice, lifted = lift(tree, seq.uv, seq.root_depth, F, anchor=anchor)
    rel_w, mpjpe_w = _errors(choice, seq, lengths)
    rel_r, mpjpe_r = _errors(lifted, seq, lengths)
    assert rel_r < 0.6 * rel_w
    assert mpjpe_r < 0.8 * mpjpe_w
    # Not converged is the default budget's (LiftOptions.max_steps = 8, as in the benchmark's
    # speed figures), not a failure: the refinement meets its tolerance here in 10 steps, at
    # the same answer (length error 1.10 % against 1.11 % after 8; MPJPE 62.2 mm and
    # reprojection 1.121 px both).
    status = int(lifted.status)
    assert status == FitStatus.CONVERGED or (
        status == FitStatus.NOT_CONVERGED and int(lifted.steps) == LiftOptions().max_steps
    )
    assert float(lifted.reprojection_rms) < 2.0  # px, at 1 px noise
    groups = tree.length_groups(True)  # symmetric lengths by default
    for k, g in enumerate(groups):
        assert float(lifted.lengths[k]) == float(lifted.lengths[groups.index(g)])


def test_the_length_prior_leaves_lengths_the_images_pin(tree, noisy_walk):
    """The walk seen from the front, 60 frames, 1 px: the images pin every length (1.1 %
    without the prior); with ANSUR II's prior (`length_prior`) they move by less than
    0.5 % of themselves."""
    seq, _ = noisy_walk
    anchor = np.asarray(true_reflections(tree, seq.joints))[0]
    _, plain = lift(tree, seq.uv, seq.root_depth, F, anchor=anchor)
    options = LiftOptions(prior=length_prior(tree, "male"))
    _, held = lift(tree, seq.uv, seq.root_depth, F, anchor=anchor, options=options)
    change = np.abs(np.asarray(held.lengths) / np.asarray(plain.lengths) - 1)
    assert change.max() < 0.005, change


def test_robust_loss_resists_wrong_detections(tree, noisy_walk):
    """Six detections off by some 40 px: the Cauchy loss keeps the joints closer than plain
    least squares (robust = 1e6 sigmas is plain least squares, in the same compiled solve)."""
    seq, lengths = noisy_walk
    rng = np.random.default_rng(0)
    uv = np.array(seq.uv)
    wrong = rng.choice(uv.shape[0] * uv.shape[1], 6, replace=False)
    uv.reshape(-1, 2)[wrong] += rng.normal(0.0, 40.0, (6, 2))
    anchor = np.asarray(true_reflections(tree, seq.joints))[0]
    _, robust = lift(tree, uv, seq.root_depth, F, anchor=anchor)
    _, plain = lift(tree, uv, seq.root_depth, F, anchor=anchor, options=LiftOptions(robust=1e6))
    assert _errors(robust, seq, lengths)[1] < 0.8 * _errors(plain, seq, lengths)[1]


def test_refinement_failure_is_a_status(tree, noisy_walk):
    """A start far off (every part 5 m long) with too few steps to settle (2; it takes 37):
    NOT_CONVERGED, the last iterate (moved off the start, not returned as a failure), every
    number finite."""
    seq, _ = noisy_walk
    from diffbody.images._lifting import refine

    start = np.array(seq.joints)
    out = refine(
        tree, seq.uv, seq.root_depth, F, start, np.full(tree.n_parts, 5.0), LiftOptions(max_steps=2)
    )
    assert int(out.status) == FitStatus.NOT_CONVERGED and int(out.steps) == 2
    assert np.all(np.isfinite(np.asarray(out.joints))) and np.all(
        np.isfinite(np.asarray(out.lengths))
    )
    assert np.all(np.asarray(out.lengths) < 5.0)  # the iterate, not the start
    with pytest.raises(ValueError, match="init_lengths must be finite numbers > 0"):
        refine(tree, seq.uv, seq.root_depth, F, start, np.zeros(tree.n_parts))
    with pytest.raises(ValueError, match="options.accel_sigma must be a finite number > 0"):
        refine(
            tree,
            seq.uv,
            seq.root_depth,
            F,
            start,
            np.ones(tree.n_parts),
            LiftOptions(accel_sigma=0.0),
        )


# --- the structured solver against a dense one, and the residuals' derivatives -------------
def _structured_operator(T=7, E=3, q=2, m=2, a=5, r=3, seed=0):
    """A random linear map FrameUnknowns -> FrameResiduals with the solver's sparsity:
    frame rows see one frame and the border, window rows one entity over three frames."""
    rng = np.random.default_rng(seed)
    Jf = jnp.asarray(rng.normal(size=(T, a, E * q)))
    Jfb = jnp.asarray(rng.normal(size=(T, a, m)))
    Jw = jnp.asarray(rng.normal(size=(T - 2, E, r, 3, q)))
    Jwb = jnp.asarray(rng.normal(size=(T - 2, E, r, m)))

    def mv(x: FrameUnknowns) -> FrameResiduals:
        fr = jnp.einsum("tai,ti->ta", Jf, x.frames.reshape(T, -1)) + Jfb @ x.border
        win = jnp.stack([x.frames[s : s + T - 2] for s in range(3)], axis=2)  # (T-2, E, 3, q)
        w = jnp.einsum("tersq,tesq->ter", Jw, win) + Jwb @ x.border
        return FrameResiduals(frame=fr, window=w)

    x0 = FrameUnknowns(border=jnp.zeros(m), frames=jnp.zeros((T, E, q)))
    op = lx.FunctionLinearOperator(mv, jax.eval_shape(lambda: x0))
    b = FrameResiduals(
        frame=jnp.asarray(rng.normal(size=(T, a))),
        window=jnp.asarray(rng.normal(size=(T - 2, E, r))),
    )
    return op, b, x0


def test_banded_solver_matches_dense_least_squares():
    op, b, x0 = _structured_operator()
    ours = lx.linear_solve(op, b, BandedSchurCholesky()).value
    dense = lx.linear_solve(op, b, lx.QR()).value
    np.testing.assert_allclose(ours.frames, dense.frames, atol=1e-10)
    np.testing.assert_allclose(ours.border, dense.border, atol=1e-10)
    # Levenberg-Marquardt's damped stack [J; sqrt(lambda) I], as optimistix builds it
    from optimistix._solver.levenberg_marquardt import _Damped

    damped = lx.FunctionLinearOperator(_Damped(op, jnp.asarray(0.7)), op.in_structure())
    vec = (b, jax.tree.map(jnp.zeros_like, x0))
    ours = lx.linear_solve(damped, vec, BandedSchurCholesky()).value
    dense = lx.linear_solve(damped, vec, lx.QR()).value
    np.testing.assert_allclose(ours.frames, dense.frames, atol=1e-10)
    np.testing.assert_allclose(ours.border, dense.border, atol=1e-10)


def test_residual_derivatives(tree, noisy_walk):
    """The refinement's residuals: jacfwd = jacrev = central differences, at a point away
    from the start, with the hinge rows on."""
    from diffbody.images import _lifting

    seq, lengths = noisy_walk
    T = 6
    options = jax.tree.map(jnp.asarray, LiftOptions(limits=((8, 3, 0.3),)))
    groups = tree.length_groups(True)
    joints = jnp.asarray(seq.joints[:T])
    s, e = np.asarray(tree.part_start), np.asarray(tree.part_end)
    d0 = joints[:, e] - joints[:, s]
    d0 = d0 / jnp.linalg.norm(d0, axis=-1, keepdims=True)
    e1, e2 = _lifting.tangent_basis(d0)
    pb = _lifting._Problem(
        jnp.log(jnp.asarray(lengths[[groups.index(g) for g in range(8)]])),
        jnp.asarray(seq.uv[:T]),
        jnp.asarray(seq.root_depth[:T]),
        jnp.asarray(F),
        joints[:, tree.root, :2],
        d0,
        e1,
        e2,
    )
    rng = np.random.default_rng(1)
    y = FrameUnknowns(
        border=pb.log_len0 + 0.01, frames=jnp.asarray(0.05 * rng.normal(size=(T, 15, 2)))
    )
    flat, unravel = jax.flatten_util.ravel_pytree(y)

    def f(v):
        r = _lifting._residuals(unravel(v), (tree, options, groups, pb))
        return jnp.concatenate([r.frame.ravel(), r.window.ravel()])

    jf = jax.jit(jax.jacfwd(f))(flat)
    jr = jax.jit(jax.jacrev(f))(flat)
    np.testing.assert_allclose(jf, jr, atol=1e-8)
    direction = jnp.asarray(rng.normal(size=flat.shape))
    h = 1e-6
    fd = (f(flat + h * direction) - f(flat - h * direction)) / (2 * h)
    np.testing.assert_allclose(jf @ direction, fd, rtol=1e-5, atol=1e-5)
    assert np.all(np.isfinite(np.asarray(jf)))


# --- the semi-real walk ----------------------------------------------------------------------
def test_semi_real_walk_joints(tree):
    """The walk's joint centres from markers: 151 frames of the default tree, parts rigid
    to within a centimetre (skin and marker motion), the data file equal to the function."""
    times, joints = load_walk_joints()
    assert joints.shape == (151, 15, 3)
    assert (times[-1] - times[0]) / 150 == pytest.approx(1 / 60, rel=1e-2)  # 60 Hz
    assert NAMES == tree.names
    L = np.linalg.norm(joints[:, list(tree.part_end)] - joints[:, list(tree.part_start)], axis=-1)
    assert np.all(L.std(axis=0) < 0.01)
    assert 0.40 < np.median(L[:, tree.part_names.index("left_hip->left_knee")]) < 0.50
    root = Path(__file__).resolve().parents[2] / "data" / "mocap"
    if not (root / "subject01_walk1.trc").exists():
        pytest.skip("data/mocap is not in this checkout")
    from diffbody.files._trc import read_trc

    fresh = joint_centres_from_markers(
        read_trc(root / "subject01_walk1.trc"), read_trc(root / "subject01_static.trc")
    )
    np.testing.assert_allclose(fresh, joints, atol=1e-6)


def test_reflection_codes(tree):
    assert NEAR == 0
    joints, _ = _sweeping(tree, 10)
    refl = np.asarray(true_reflections(tree, joints))
    E, S = joints[:, list(tree.part_end)], joints[:, list(tree.part_start)]
    far = np.einsum("tpc,tpc->tp", E, E - S) > 0
    np.testing.assert_array_equal(refl, far.astype(int))
    assert math.isclose(refl.mean(), far.mean())
