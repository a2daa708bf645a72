"""Motion capture: scaling and registration on a static trial, the posture of every frame,
and the bone descriptors over time (diffbody.mocap: _static_fit, _motion_fit;
diffbody._descriptors).

The synthetic subject is the male median body scaled by known axial factors, with the
shipped marker set carried to it (`scale_offsets`), posed by known free vectors; its
markers come from `world_markers` (the walk of `forward`, not the fit's own kernel). One
static fit and one motion fit shape are compiled for the whole module."""

import dataclasses
import re
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import counted_compiles
from hypothesis import given
from hypothesis import strategies as st

import diffbody as db
from diffbody._descriptors import descriptors, unwrap_directions
from diffbody._rotations import exp_rotvec
from diffbody.anthropometry._scale_to import LENGTHS, linear_model_jit
from diffbody.anthropometry._scaling import N_GROUPS, SCALE_GROUPS, per_segment
from diffbody.clouds._cloud_fit import FitStatus
from diffbody.files._data_files import data_file
from diffbody.files._marker_trial import MarkerTrial
from diffbody.files._markerset_file import load_markerset
from diffbody.files._motion_files import read_mot
from diffbody.mocap._marker_layout import mocap_layout, rigid_fit, rotation_vector
from diffbody.mocap._marker_points import model_markers, tree_markers
from diffbody.mocap._markerset import MarkerWarning, scale_offsets, world_markers
from diffbody.mocap._mocap_solver import MIN_MARKERS, robust_rows
from diffbody.mocap._motion_fit import FRAME_STEPS, VELOCITY, _frame_residuals, fit_motion
from diffbody.mocap._motion_limits import MOTION_RANGES, motion_limits
from diffbody.mocap._motion_registration import MOTION_FRAMES
from diffbody.mocap._static_fit import PRIOR_MEASUREMENTS, population_prior, scale_and_register
from diffbody.mocap._trial_outputs import save_angles, save_coordinates, scaled_body
from diffbody.problem._points import walk_points
from diffbody.problem._problem import make_problem

N_FRAMES = 4
NOISE = 0.005  # m, per coordinate


def trial_of(names, positions, source="synthetic") -> MarkerTrial:
    positions = np.asarray(positions, float)
    times = np.arange(len(positions)) / 100.0
    return MarkerTrial(names=names, times=times, positions=positions, rate=100.0, source=source)


@pytest.fixture(scope="module")
def gait(male50):
    return load_markerset("opensim-gait", male50)


@pytest.fixture(scope="module")
def subject(male50, gait):
    """The scaled person, its marker set, a static pose and a smooth 4-frame motion (a
    walk's translation plus posture changes), and their markers."""
    rng = np.random.default_rng(3)
    axial = np.exp(0.05 * rng.standard_normal(N_GROUPS))
    axial[list(SCALE_GROUPS).index("hand")] = 1.0  # no marker sees the hands
    a = per_segment(male50, axial)
    ones = jnp.ones_like(a)
    person = db.scale_body(male50, a, ones)
    markers = scale_offsets(gait, male50, a, ones)
    lay = mocap_layout(person, markers)
    rest = person.rest_pose()
    # Compiled (op by op, the set-up's operations are hundreds of programs).
    problem = eqx.filter_jit(make_problem)(person, lay.pose, rest)
    pose_of = eqx.filter_jit(lambda problem, x: problem.pose(x, rest))
    n = lay.pose.n_free
    x_static = np.asarray(problem.x0) + 0.15 * rng.standard_normal(n)
    x_static[-6:] = [0.3, -0.1, 0.0, 0.0, 0.0, 0.4]  # placed and turned
    step = 0.05 * rng.standard_normal(n)
    step[-6:] = [0.04, 0.0, 0.0, 0.0, 0.0, 0.02]  # walking forward, turning a little
    xs = [x_static + t * step for t in range(1, N_FRAMES + 1)]
    fk = jax.jit(lambda pose: (world_markers(person, pose, markers), db.forward(person, pose)))
    static_pose = pose_of(problem, jnp.asarray(x_static))
    poses = [pose_of(problem, jnp.asarray(x)) for x in xs]
    static_markers = np.asarray(fk(static_pose)[0])
    out = [fk(p) for p in poses]
    return {
        "axial": axial,
        "person": person,
        "static_pose": static_pose,
        "static_markers": static_markers,
        "joints_static": np.asarray(fk(static_pose)[1].joint_positions),
        "walk": np.stack([np.asarray(m) for m, _ in out]),
        "joints": np.stack([np.asarray(k.joint_positions) for _, k in out]),
    }


@pytest.fixture(scope="module")
def static_fit(male50, gait, subject):
    """Noiseless static trial (two identical frames), offsets started at the truth, no
    prior (float64)."""
    trial = trial_of(gait.names, np.stack([subject["static_markers"]] * 2))
    return scale_and_register(male50, trial, gait, prior=False)


@pytest.fixture(scope="module")
def noisy_static_fit(male50, gait, subject):
    """The same with 5 mm of noise per coordinate: the same compiled fit."""
    rng = np.random.default_rng(11)
    noisy = subject["static_markers"] + NOISE * rng.standard_normal((2,) + gait.offsets.shape)
    return scale_and_register(male50, trial_of(gait.names, noisy), gait, prior=False)


@pytest.fixture(scope="module")
def motion(static_fit, subject):
    """`fit_motion` of the subject's markers from the static fit; the velocity term off
    unless asked for (it leans each frame toward the previous one: the exact fit is the
    test)."""

    def run(positions, **kwargs):
        kwargs.setdefault("velocity", False)
        trial = trial_of(static_fit.markerset.names, positions)
        return fit_motion(
            static_fit.body, static_fit.markerset, trial, start=static_fit.pose, **kwargs
        )

    return run


# --- the static fit ---------------------------------------------------------------------------
def test_static_fit_recovers_the_scale_factors_and_the_pose(static_fit, subject):
    """Noiseless markers of a scaled, posed body: every axial factor to 1e-6 relative, the
    markers to a micrometre, every joint to 1e-6 m; the registered set puts the markers back
    where they were measured through `world_markers`."""
    assert static_fit.status == FitStatus.CONVERGED
    np.testing.assert_allclose(static_fit.axial, subject["axial"], rtol=1e-6)
    assert np.max(static_fit.errors) < 1e-6
    joints = db.forward(static_fit.body, static_fit.pose).joint_positions
    np.testing.assert_allclose(joints, subject["joints_static"], atol=1e-6)
    placed = world_markers(static_fit.body, static_fit.pose, static_fit.markerset)
    np.testing.assert_allclose(placed, subject["static_markers"], atol=1e-6)


def test_noisy_static_fit_finds_the_lengths(noisy_static_fit, subject):
    """5 mm noise on every coordinate of the (averaged) static trial: the limbs' lengths
    within 5 mm, each marker's error about the noise."""
    fit = noisy_static_fit
    assert fit.status == FitStatus.CONVERGED
    for name in ("left_thigh", "left_shank", "left_upper_arm", "left_forearm", "left_foot"):
        i = fit.body.segment_index(name)
        assert abs(float(fit.body.lengths[i] - subject["person"].lengths[i])) < 0.005, name
    # Each marker's offset moves within its tolerance (5 mm for the landmarks): the errors
    # stay below the noise's 3D norm, 5 mm * sqrt(3) at about 2 standard deviations.
    assert np.sqrt(np.mean(np.asarray(fit.errors) ** 2)) < 2 * NOISE * np.sqrt(3)


def test_prior_measurements_are_lengths(male50):
    """The prior's measurements are decided by the axial factors (at least 80 % of each,
    the rest being sphere radii at an extent), and its linear model reproduces `measure`
    on a scaled body exactly (the measurements are linear within a piece)."""
    A = np.asarray(linear_model_jit(male50, jnp.ones(2 * N_GROUPS)))
    rows = A[[LENGTHS.index(n) for n in PRIOR_MEASUREMENTS]]
    assert np.all(rows[:, :N_GROUPS].sum(1) >= 0.8 * rows.sum(1))
    prior = population_prior(True, male50, None, ("lengths", "offsets"))
    s = 1.0 + 0.02 * np.sin(np.arange(N_GROUPS))
    a = per_segment(male50, s)
    scaled = db.scale_body(male50, a, jnp.ones_like(a))
    np.testing.assert_allclose(
        prior.A @ np.concatenate([s, np.ones(N_GROUPS)]),
        db.measure(scaled, PRIOR_MEASUREMENTS),
        rtol=1e-9,
    )


# --- every frame ---------------------------------------------------------------------------
def test_motion_fit_recovers_the_poses(motion, subject):
    """Noiseless markers of a smooth motion (a walk forward while turning): without the
    velocity term, every frame's markers to 1e-6 m and its joints to 1e-5 m. With it (the
    default), within 0.5 mm: the term leans each frame toward the previous one, most on the
    head's markers, which hold its posture least (every unknown moves 0.05 rad a frame, 3
    rad/s at 60 Hz)."""
    leaning = motion(subject["walk"], velocity=True)
    assert np.all(leaning.status == FitStatus.CONVERGED) and np.max(leaning.errors) < 5e-4
    fit = motion(subject["walk"])
    assert np.all(fit.status == FitStatus.CONVERGED)
    assert np.max(fit.errors) < 1e-6 and np.max(fit.rms) < 1e-6
    for k in range(N_FRAMES):
        joints = db.forward(subject["person"], fit.pose(k)).joint_positions
        np.testing.assert_allclose(joints, subject["joints"][k], atol=1e-5)
    per = fit.per_marker()
    assert set(per) == set(fit.names) and max(m for _, m in per.values()) < 1e-6


def test_a_frames_velocity_rows_are_its_step_from_the_previous_frame(static_fit):
    """A frame's rows end with its velocity term, weight (x - x_before) (`VELOCITY`); at
    weight 0 the other rows are unchanged, so the term off is the fit without it."""
    body = motion_limits(static_fit.body)
    lay = mocap_layout(body, static_fit.markerset)
    rng = np.random.default_rng(5)
    dx, d_before = 0.1 * rng.standard_normal((2, lay.pose.n_free))

    # One program (op by op, the problem and the walk are hundreds of programs).
    @eqx.filter_jit
    def rows(weight):
        problem = make_problem(body, lay.pose, static_fit.pose)
        x, before = problem.x0 + dx, problem.x0 + d_before
        target = model_markers(problem, lay, static_fit.markerset.offsets, problem.x0)
        sqrt_w = jnp.full(len(target), 100.0)
        args = (problem, lay, static_fit.markerset.offsets, target, sqrt_w, problem.x0, 0.03)
        return _frame_residuals(x, (*args, before, weight)), x - before

    (on, step), (off, _) = (jax.device_get(rows(jnp.asarray(w))) for w in (VELOCITY, 0.0))
    n = lay.pose.n_free
    np.testing.assert_allclose(on[-n:], VELOCITY * step, rtol=1e-12)
    np.testing.assert_array_equal(off[-n:], 0.0)
    np.testing.assert_array_equal(on[:-n], off[:-n])


def test_noisy_motion_errors_are_the_noise(motion, subject, static_fit):
    """5 mm noise per coordinate: the reported errors are least-squares residuals of n = 49
    markers (3n rows) against p unknowns, whose mean square is 5 mm^2 (3n - p) / n per
    marker; the pooled RMS lies within 20 % of 5 mm sqrt((3n - p) / n)."""
    rng = np.random.default_rng(5)
    noisy = subject["walk"] + NOISE * rng.standard_normal(subject["walk"].shape)
    fit = motion(noisy)
    n, p = len(fit.names), mocap_layout(static_fit.body, static_fit.markerset).pose.n_free
    expected = NOISE * np.sqrt((3 * n - p) / n)
    pooled = np.sqrt(np.mean(fit.errors**2))
    assert 0.8 * expected < pooled < 1.2 * expected
    np.testing.assert_allclose(fit.rms, np.sqrt(np.mean(fit.errors**2, axis=1)))
    np.testing.assert_allclose(fit.max, np.max(fit.errors, axis=1))
    summary = fit.summary()
    assert summary["anatomical_rms"] > 0 and summary["tracking_rms"] > 0


def test_missing_markers(motion, subject, static_fit):
    """A marker missing in some frames, another in every frame (dead: one warning names it):
    every frame still fits its present markers exactly, and the errors are NaN where a
    marker was missing."""
    walk = subject["walk"].copy()
    walk[1:3, 5] = np.nan
    walk[:, 20] = np.nan
    name = static_fit.markerset.names[20]
    with pytest.warns(MarkerWarning, match=re.escape(f"{name} (no data)")):
        fit = motion(walk)
    assert fit.dead == ((fit.names[20], "no data"),)
    assert np.all(fit.status == FitStatus.CONVERGED)
    missing = np.isnan(walk).any(-1)
    assert np.array_equal(np.isnan(fit.errors), missing)
    assert np.nanmax(fit.errors) < 1e-6 and np.all(np.isfinite(fit.rms))
    assert np.isnan(fit.per_marker()[fit.names[20]][0])


def test_a_frame_with_too_few_markers_fails_without_nan(motion, subject):
    """A frame with fewer than MIN_MARKERS markers keeps its predecessor's posture and says
    FAILED; the frames after it are fitted again."""
    walk = subject["walk"].copy()
    walk[2, MIN_MARKERS - 1 :] = np.nan
    fit = motion(walk)
    assert fit.status[2] == FitStatus.FAILED
    assert np.all(fit.status[[0, 1, 3]] == FitStatus.CONVERGED)
    np.testing.assert_allclose(fit.poses.angles[2], fit.poses.angles[1])
    assert all(np.all(np.isfinite(a)) for a in jax.tree.leaves(fit.poses))
    assert np.all(np.isfinite(fit.rms)) and np.max(fit.errors[3]) < 1e-6


def test_weights_select_markers(motion, subject, static_fit):
    """A {marker: weight} mapping: the markers it leaves out take no part (their errors are
    still reported)."""
    walk = subject["walk"].copy()
    walk[:, 0, 0] += 0.05  # R.ASIS displaced: left out, it does not pull the pelvis
    fit = motion(walk, weights={n: 1.0 for n in static_fit.markerset.names[1:]})
    assert np.max(fit.errors[:, 1:]) < 1e-6
    np.testing.assert_allclose(fit.errors[:, 0], 0.05, rtol=1e-4)


# --- the shipped trials, as a user runs them -----------------------------------------------
@pytest.fixture(scope="module")
def shipped():
    """The README's workflow on the shipped OpenSim example (data/mocap), with the default
    population prior and in JAX's default float32, as a user runs it: the registration on
    the static trial and 8 frames of the walk, and the whole walk. Returns the registration,
    the motion fit, and the registration on the static trial alone with its scaled body's
    `PRIOR_MEASUREMENTS` (the first solve of the other: the same compiled fit)."""
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.simplefilter("ignore", MarkerWarning)
        body = db.load_body(variant="male50")
        static = db.read_trc(data_file("mocap/subject01_static.trc"))
        walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
        gait = db.load_markerset("opensim-gait", body)
        fit = db.scale_and_register(body, static, gait, motion=walk)
        ms = fit.markerset.select(walk.names)
        motion = db.fit_motion(fit.body, ms, walk, start=fit.pose, scale=fit.marker_scale)
        alone = db.scale_and_register(body, static, gait)
        measured = db.measurements(alone.body, PRIOR_MEASUREMENTS)
    return fit, motion, alone, measured


def test_default_static_fit_on_the_shipped_trial(shipped):
    """Scaling and registration on the static trial alone under the ANSUR II prior:
    converged (float32); the
    registered markers within 15 mm RMS of the averaged static trial (12.4 mm; the largest,
    the sternum's, 56 mm); every axial factor between 0.8 and 1.3 (without the prior the
    thorax, which no marker spans, shrinks to 0.03); the stature within 1.5 cm of the
    subject's 1.803 m (OpenSim's scale setup, data/mocap/README.md), and each measurement
    the factors decide within 3 standard deviations of the male population's given the
    others."""
    _, _, fit, measured = shipped
    assert fit.motion_errors is None and fit.motion_frames == ()
    assert int(fit.status) == FitStatus.CONVERGED and fit.body.lengths.dtype == jnp.float32
    errors = np.asarray(fit.errors)
    assert np.all(np.isfinite(errors)) and np.sqrt(np.mean(errors**2)) < 0.015
    assert errors.max() < 0.07
    axial = np.asarray(fit.axial)
    assert np.all((axial > 0.8) & (axial < 1.3)), dict(zip(SCALE_GROUPS, axial.round(3)))
    assert abs(measured["stature"] - 1.803) < 0.015
    assert db.PopulationPrior.ansur2("male").outliers(measured, 3.0) == []


def test_default_motion_fit_on_the_shipped_walk(shipped):
    """Every frame of the walk (151, 41 markers) from the default registration (the static
    trial and 8 frames of the walk), robust loss and motion limits: converged; per-frame
    marker RMS 7.7 mm on average (bounds 9 and 12 mm; registered on the static trial alone,
    18.7 mm: the arms' markers, registered in its T-pose, sat 3-5 cm off while walking);
    the pelvis and leg markers within 2 cm RMS each; no marker flagged. The largest error
    under 5 cm (36 mm, the left midfoot's). The first frame, solved from the static pose and
    from the standard position, is within 20 % of the median frame's RMS (regression: from
    the T-pose alone it was 4-5 times the others' on a running trial)."""
    fit, motion, _, _ = shipped
    assert motion.status.shape == (151,) and np.all(motion.status == FitStatus.CONVERGED)
    assert np.mean(motion.rms) < 0.009 and np.max(motion.rms) < 0.012
    assert np.nanmax(motion.errors) < 0.05
    assert abs(motion.rms[0] - np.median(motion.rms)) < 0.2 * np.median(motion.rms)
    assert motion.flagged() == {} and not motion.dead
    summary = motion.summary()
    assert summary["inlier_rms"] <= summary["rms"] < 0.009
    names = fit.body.segment_names
    lower = ("pelvis", "thigh", "shank", "foot")
    per = motion.per_marker()
    for name in motion.names:
        segment = names[fit.markerset.segments[fit.markerset.index(name)]]
        if segment.endswith(lower):
            assert per[name][0] < 0.02, (name, segment, per[name])


def test_every_trial_length_and_marker_order_is_one_compiled_fit(shipped):
    """The registration fitted its 8 frames with the program that fits the walk
    (`CHUNK_FRAMES` frames a call, a trial's last chunk padded with frames that see
    nothing). The walk with its markers in reverse order, and a part of it of another
    length, compile nothing; the whole walk gives the same answers, marker for marker, and
    the part's frames are as good."""
    fit, motion, _, _ = shipped
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    names = motion.names[::-1]
    with jax.enable_x64(False), warnings.catch_warnings(), counted_compiles() as compiles:
        warnings.simplefilter("ignore", MarkerWarning)
        ms, reversed_walk = fit.markerset.select(names), walk.select(names)
        args = dict(start=fit.pose, scale=fit.marker_scale)
        again = fit_motion(fit.body, ms, reversed_walk, **args)
        part = fit_motion(fit.body, ms, reversed_walk.between(0.5, 1.5), **args)
    assert compiles == [] and again.names == names
    order = [motion.names.index(n) for n in names]
    np.testing.assert_allclose(again.errors, motion.errors[:, order], rtol=0, atol=1e-6)
    np.testing.assert_allclose(again.rms, motion.rms, rtol=0, atol=1e-6)
    assert part.status.shape == (61,) and np.all(part.status == FitStatus.CONVERGED)
    assert np.mean(part.rms) < 0.009


def test_a_folder_of_trials_reuses_the_workflows_programs(shipped, tmp_path):
    """`fit_trials` on a folder of two parts of the walk (61 and 31 frames) after the
    README's workflow in the same process (the `shipped` fixture): its registration (on the
    static trial and 8 frames spread over both parts), both trials' fits and their files
    compile nothing: one registration program, one motion-fit program for every trial
    (regression: the scaled body's file indexed device arrays, a small program per shape)."""
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    folder = tmp_path / "trials"
    folder.mkdir()
    db.write_trc(folder / "a.trc", walk.between(0.5, 1.5))
    db.write_trc(folder / "b.trc", walk.between(1.6, 2.1))
    with jax.enable_x64(False), warnings.catch_warnings(), counted_compiles() as compiles:
        warnings.simplefilter("ignore", MarkerWarning)
        result = db.fit_trials(
            db.load_body(variant="male50"),
            data_file("mocap/subject01_static.trc"),
            folder,
            "opensim-gait",
            tmp_path / "fits",
            log=lambda line: None,
        )
    assert result.ok and result.fitted == ("a.trc", "b.trc")
    assert compiles == []


def test_the_velocity_term_barely_moves_what_the_markers_decide(shipped):
    """The velocity term (on by default) chooses between postures that fit about equally
    well: off, the shipped walk's frames all converge, the mean marker RMS within 0.01 mm of
    the default's and each frame's within 0.25 mm (0.001 and 0.17 mm measured), from the same
    compiled fit (the weight is data)."""
    fit, motion, _, _ = shipped
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    with jax.enable_x64(False), counted_compiles() as compiles:
        ms = fit.markerset.select(walk.names)
        args = dict(start=fit.pose, scale=fit.marker_scale, velocity=False)
        off = fit_motion(fit.body, ms, walk, **args)
    assert compiles == [] and np.all(off.status == FitStatus.CONVERGED)
    assert abs(np.mean(off.rms) - np.mean(motion.rms)) < 1e-5
    assert np.max(np.abs(off.rms - motion.rms)) < 2.5e-4


def test_the_walk_shows_the_shoulders_the_static_trial_hides(shipped):
    """On the shipped walk the static trial alone registers the arms' markers in its T-pose
    and the walk's mean marker RMS is 18.7 mm (benchmarks/mocap.py); registered on 8 of
    the walk's frames as well it is 7.3 mm (AddBiomechanics' published figure is about 15
    mm), every frame converged. The clavicles take the shoulder width the walk shows
    (acromia 419 mm apart, against 342 mm in the T-pose): their scale factor grows by more
    than 0.04 over the static trial's alone (0.89 to 0.95-0.97). The static trial's markers
    stay within 6 cm (the acromia, 5.3 cm, are where the T-pose differs)."""
    fit, walk, alone, _ = shipped
    assert int(fit.status) == FitStatus.CONVERGED
    assert len(fit.motion_frames) == MOTION_FRAMES
    frames = [f for _, f in fit.motion_frames]
    assert frames[0] == 0 and frames[-1] == 150 and np.all(np.diff(frames) >= 20)
    assert fit.motion_errors.shape == (MOTION_FRAMES, len(fit.markerset.names))
    assert np.mean(walk.rms) < 0.009 and np.all(walk.status == FitStatus.CONVERGED)
    clavicle = list(SCALE_GROUPS).index("clavicle")
    assert float(fit.axial[clavicle]) > float(alone.axial[clavicle]) + 0.04
    assert np.nanmax(np.asarray(fit.errors)) < 0.06
    # The registration's own frames: within 1.5 cm RMS each (6.5-12.4 mm; the walk's fit,
    # each frame from its neighbour, takes them on to 6.5-9.7 mm).
    names = list(fit.markerset.names)
    cols = [names.index(n) for n in walk.names]
    e = np.asarray(fit.motion_errors)[:, cols]
    assert np.all(np.sqrt(np.nanmean(e**2, axis=1)) < 0.015)
    # Dimensions a person has: each measurement the factors decide within 3 standard
    # deviations of the male population's given the others. The stature comes out 1.82-1.83
    # m, 2-3 cm over the subject's 1.803 m (the static trial alone: within 1.5 cm): the walk
    # lengthens the pelvis and the lumbar spine (factors 1.32-1.34 and 1.07-1.15);
    # `measured={"stature": ...}` holds it to a tape reading.
    measured = db.measurements(fit.body, PRIOR_MEASUREMENTS)
    assert db.PopulationPrior.ansur2("male").outliers(measured, 3.0) == []
    assert 0.0 < measured["stature"] - 1.803 < 0.035


def test_the_walks_joint_angles_do_not_jump(shipped):
    """Registered on the walk too, every ISB joint angle of the shipped walk moves at most 10
    degrees from one frame to the next (600 deg/s at 60 Hz: above the knee's swing, about 8.8
    deg the largest measured, the right ankle's inversion). Registered on the static trial
    alone, the left arm switched between two postures between frames 100 and 101 (the arm's
    rotation by 83 degrees, the elbow by 44) as its badly registered markers drifted: a jump
    the markers do not show (without the velocity term it still does:
    `test_the_velocity_term_keeps_an_arm_from_flipping`)."""
    fit, walk, _, _ = shipped
    worst, step = _largest_step(walk, fit.body)
    assert step < 10.0, (worst, step)


# --- faults of real recordings, injected into copies of the shipped walk --------------------
def _faulted(walk: MarkerTrial, kind: str, folder) -> tuple[MarkerTrial, tuple[str, ...]]:
    """A copy of the walk with one fault, written as a TRC file and read back (a zero is
    written as 0.000, as exporters do), and the markers it touched."""
    rng = np.random.default_rng(0)
    P = walk.positions.copy()
    at = {name: k for k, name in enumerate(walk.names)}
    some = rng.choice(walk.n_frames, walk.n_frames // 10, replace=False)
    if kind == "dead":  # (0, 0, 0) in every frame
        touched = ("L.Elbow",)
        P[:, at["L.Elbow"]] = 0.0
    elif kind == "gaps":  # (0, 0, 0) in 10 % of the frames
        touched = ("R.Heel",)
        P[some, at["R.Heel"]] = 0.0
    elif kind == "swapped":  # neighbours' labels swapped for 20 frames (10-12 cm apart)
        touched = ("R.Thigh.Front", "R.Thigh.Rear")
        a, b = at[touched[0]], at[touched[1]]
        P[60:80, a], P[60:80, b] = walk.positions[60:80, b], walk.positions[60:80, a]
    elif kind == "jumps":  # 20-40 cm off in 10 % of the frames
        touched = ("L.Shank.Front",)
        d = rng.normal(size=(len(some), 3))
        d *= rng.uniform(0.2, 0.4, (len(some), 1)) / np.linalg.norm(d, axis=1, keepdims=True)
        P[some, at["L.Shank.Front"]] += d
    else:  # "moved": 15 cm off for the whole trial
        touched = ("L.Thigh.Front",)
        P[:, at["L.Thigh.Front"]] += 0.15 * np.array([0.0, 0.6, 0.8])
    path = folder / f"{kind}.trc"
    db.write_trc(path, dataclasses.replace(walk, positions=P))
    return db.read_trc(path), touched


FAULTS = ("dead", "gaps", "swapped", "jumps", "moved")


@pytest.fixture(scope="module")
def faulted_fits(shipped, tmp_path_factory):
    """Each fault's trial fitted as the clean walk (the same compiled fit: a dead marker
    keeps its place with no weight)."""
    fit, _, _, _ = shipped
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    folder = tmp_path_factory.mktemp("faults")
    ms = fit.markerset.select(walk.names)
    out = {}
    with jax.enable_x64(False):
        for kind in FAULTS:
            trial, touched = _faulted(walk, kind, folder)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", MarkerWarning)
                motion = db.fit_motion(fit.body, ms, trial, start=fit.pose, scale=fit.marker_scale)
            out[kind] = (motion, touched, [str(w.message) for w in caught])
    return out


@pytest.mark.parametrize("kind", FAULTS)
def test_a_faulty_marker_changes_nothing_else(shipped, faulted_fits, kind):
    """Each fault: every frame converges; the RMS over the untouched markers stays within
    2 mm of the clean fit's (measured: within 0.8 mm); the first frame's RMS over them
    within 20 % of their median frame's; `flagged` names the faulty markers and nothing
    else (dead: "no data", with one warning naming it; zeros in 10 % of the frames: missing
    there; the others: outliers in more than 5 % of the frames that see them)."""
    _, clean, _, _ = shipped
    motion, touched, caught = faulted_fits[kind]
    keep = [k for k, n in enumerate(clean.names) if n not in touched]
    assert motion.names == clean.names and np.all(motion.status == FitStatus.CONVERGED)
    rms = [np.sqrt(np.nanmean(m.errors[:, keep] ** 2)) for m in (motion, clean)]
    assert abs(rms[0] - rms[1]) < 0.002, rms
    frames = np.sqrt(np.nanmean(motion.errors[:, keep] ** 2, axis=1))
    assert abs(frames[0] - np.median(frames)) < 0.2 * np.median(frames)
    flagged = motion.flagged()
    assert set(flagged) == set(touched), flagged
    if kind == "dead":
        dead = motion.names.index("L.Elbow")
        assert flagged == {"L.Elbow": "no data"} and np.isnan(motion.errors[:, dead]).all()
        assert len(caught) == 1 and "L.Elbow (no data)" in caught[0]
    elif kind == "gaps":
        assert flagged == {"R.Heel": "missing in 10 % of frames"} and not caught
    else:
        assert all(why.startswith("outlier in") for why in flagged.values()) and not caught
        assert motion.summary()["inlier_rms"] < motion.summary()["rms"]


def test_zeros_are_gaps(tmp_path):
    """A marker at exactly (0, 0, 0) reads as a gap (NaN) by default and as zeros with
    zero_is_gap=False; `dead` names a marker with no data and one left on the floor while
    the body walks; a standing trial names none for not moving."""
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    P = walk.positions.copy()
    P[:, 0] = 0.0
    P[5, 1] = 0.0
    P[:, 2] = [0.3, 0.2, 0.0]
    path = tmp_path / "zeros.trc"
    db.write_trc(path, dataclasses.replace(walk, positions=P))
    gaps, zeros = db.read_trc(path), db.read_trc(path, zero_is_gap=False)
    assert np.isnan(gaps.positions[:, 0]).all() and np.isnan(gaps.positions[5, 1]).all()
    assert np.isfinite(gaps.positions[:, 1:]).sum() == np.isfinite(P[:, 1:]).sum() - 3
    assert np.array_equal(zeros.positions[:, 0], np.zeros((walk.n_frames, 3)))
    assert gaps.dead() == {walk.names[0]: "no data", walk.names[2]: "does not move"}
    static = db.read_trc(data_file("mocap/subject01_static.trc"))
    assert static.dead() == {}


def test_the_mot_as_written_matches_opensim_on_the_shipped_walk(shipped, tmp_path):
    """The .mot `diffbody mocap --mot` writes (gait2354's coordinates, its frames placed
    through its Scale marker set) against OpenSim's IK answer over its 73 frames (0.4-1.6 s),
    as written, no sign applied: hip flexion, knee angle and ankle angle, both sides, RMS
    difference <= 5 degrees each (figures: README). The ISB angles' file carries ISB's names:
    no column of it is an OpenSim coordinate with another sign."""
    fit, motion, _, _ = shipped
    scaled = scaled_body(fit, fit.body)
    path = save_coordinates(tmp_path / "walk.mot", motion, fit, scaled, "walk")
    times, ours = read_mot(path)
    os_times, opensim = read_mot(data_file("mocap/subject01_walk1_ik_opensim.mot"))
    frames = np.array([int(np.argmin(np.abs(times - t))) for t in os_times])
    assert len(frames) == 73 and np.abs(times[frames] - os_times).max() < 1e-3
    figures = {}
    for name in [f"{n}_{s}" for n in ("hip_flexion", "knee_angle", "ankle_angle") for s in "rl"]:
        difference = ours[name][frames] - opensim[name]
        figures[name] = (float(np.sqrt(np.mean(difference**2))), float(np.mean(difference)))
    assert all(rms <= 5.0 for rms, _ in figures.values()), figures
    isb = read_mot(save_angles(tmp_path / "walk.angles.mot", motion, scaled, "walk"))[1]
    assert "knee_flexion_r" in isb and not set(isb) & {"knee_angle_r", "knee_angle_l"}
    assert np.mean(isb["knee_flexion_r"]) > 0 > np.mean(ours["knee_angle_r"])


@pytest.fixture(scope="module")
def walk_alone(shipped):
    """The walk fitted on the registration on the static trial alone (`shipped`'s)."""
    _, _, alone, _ = shipped
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    ms = alone.markerset.select(walk.names)
    with jax.enable_x64(False):
        return db.fit_motion(alone.body, ms, walk, start=alone.pose, scale=alone.marker_scale)


def _largest_step(fit, body) -> tuple[str, float]:
    """The ISB joint angle that moves most between two frames, and by how much (deg)."""
    with jax.enable_x64(False):
        angles = fit.angles(body)
    steps = {n: np.abs(np.diff(np.rad2deg(np.unwrap(np.deg2rad(v))))) for n, v in angles.items()}
    worst = max(steps, key=lambda n: steps[n].max())
    return worst, float(steps[worst].max())


def test_the_velocity_term_keeps_an_arm_from_flipping(shipped, walk_alone):
    """Regression for the velocity term's purpose: registered on the static T-pose alone,
    the walk's left arm markers fit two arm postures about equally well. Without the term
    the arm flips between them from one frame to the next (the shoulder's rotation by about
    105 degrees); with it (the default) no joint angle moves more than 30 degrees a frame
    (21 measured, as the first frames settle)."""
    _, _, alone, _ = shipped
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    with jax.enable_x64(False):
        ms = alone.markerset.select(walk.names)
        args = dict(start=alone.pose, scale=alone.marker_scale, velocity=False)
        flipping = db.fit_motion(alone.body, ms, walk, **args)
    name, step = _largest_step(flipping, alone.body)
    assert name.endswith("_l") and step > 60.0, (name, step)
    name, step = _largest_step(walk_alone, alone.body)
    assert step < 30.0, (name, step)


def test_opensim_places_its_markers_from_our_mot_as_from_its_own(shipped, walk_alone, tmp_path):
    """Our .mot for OpenSim's scaled model of the subject (`--opensim-model`), loaded onto
    that model by OpenSim, which places its markers frame by frame: their RMS error against
    the measured markers (OpenSim's own classes, the IK set-up's markers) within 1 cm of
    what OpenSim's own IK .mot gives on the same model, and every coordinate inside the
    model's range. OpenSim scaled that model on the static trial alone, and so is the body
    here (`--motion-frames 0`): registered on the walk too, the body differs from OpenSim's
    model (2-3 cm taller) and its .mot places the model's markers 4.5 cm from the measured
    ones against OpenSim's 2.2 cm (docs/guide.md)."""
    osim = pytest.importorskip("opensim")
    _, _, fit, _ = shipped
    motion = walk_alone
    model_path = data_file("mocap/subject01_simbody.osim")
    scaled = scaled_body(fit, fit.body)
    ours = save_coordinates(tmp_path / "walk.mot", motion, fit, scaled, "walk", model_path)
    weights = db.read_ik_tasks(data_file("mocap/subject01_Setup_IK.xml"))
    measured = osim.TimeSeriesTableVec3(str(data_file("mocap/subject01_walk1.trc")))
    ours_rms, outside = _opensim_marker_rms(osim, model_path, ours, measured, weights)
    theirs_rms, _ = _opensim_marker_rms(
        osim, model_path, data_file("mocap/subject01_walk1_ik_opensim.mot"), measured, weights
    )
    assert len(ours_rms) == len(theirs_rms) == 73 and not outside, outside
    assert np.mean(ours_rms) <= np.mean(theirs_rms) + 0.01, (ours_rms.mean(), theirs_rms.mean())


def _opensim_marker_rms(osim, model_path, mot, measured, weights):
    """Per frame of the .mot `mot` within the measured trial's time range: the RMS distance
    (m) between the model's markers, placed by OpenSim from the file's coordinates, and the
    measured ones (the markers weighted in `weights`); and the coordinates outside the
    model's ranges."""
    osim.Logger.setLevelString("error")
    model = osim.Model(str(model_path))
    state = model.initSystem()
    table = osim.TimeSeriesTable(str(mot))
    labels = list(table.getColumnLabels())
    units = 1e-3 if measured.getTableMetaDataString("Units") == "mm" else 1.0
    marker_times = np.array(measured.getIndependentColumn())
    marker_labels = list(measured.getColumnLabels())
    markers = model.getMarkerSet()
    names = [n for n, w in weights.items() if w > 0 and n in marker_labels and markers.contains(n)]
    coordinates = model.getCoordinateSet()
    rms, outside = [], []
    for i, t in enumerate(table.getIndependentColumn()):
        if t < 0.4 - 1e-6 or t > 1.6 + 1e-6:
            continue
        row = table.getRowAtIndex(i)
        for j, label in enumerate(labels):
            if coordinates.contains(label):
                c = coordinates.get(label)
                value = np.radians(row[j]) if c.getMotionType() == 1 else row[j]
                if not c.getRangeMin() - 1e-9 <= value <= c.getRangeMax() + 1e-9:
                    outside.append((t, label, value))
                c.setValue(state, value, False)
        model.realizePosition(state)
        at = measured.getRowAtIndex(int(np.argmin(np.abs(marker_times - t))))
        squared = []
        for n in names:
            q = at[marker_labels.index(n)].to_numpy() * units
            if np.all(np.isfinite(q)):
                p = markers.get(n).getLocationInGround(state).to_numpy()
                squared.append(np.sum((p - q) ** 2))
        rms.append(np.sqrt(np.mean(squared)))
    return np.array(rms), outside


def test_float64_motion_fit_converges_on_real_data(male50):
    """Regression: in float64 every frame of the shipped walk ran out of steps (tolerance
    1e-9, below what the cost resolves of the directions only the weak pull holds,
    `_mocap_solver.make_solver`). 13 frames (0.4-0.6 s) from the static fit in float64: every
    one converged, within the step limit, at float32's marker RMS (19.7-21 mm)."""
    static = db.read_trc(data_file("mocap/subject01_static.trc"))
    walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
    fit = db.scale_and_register(male50, static, db.load_markerset("opensim-gait", male50))
    part = walk.between(0.4, 0.6)
    ms = fit.markerset.select(walk.names)
    motion = db.fit_motion(fit.body, ms, part, start=fit.pose, scale=fit.marker_scale)
    assert motion.markers.dtype == np.float64 and motion.status.shape == (13,)
    assert np.all(motion.status == FitStatus.CONVERGED), motion.steps
    # Two solves a frame (`_fit_frames`), each within its limit; the first from two starts.
    assert np.all(motion.steps[1:] < 2 * FRAME_STEPS) and 0.019 < np.mean(motion.rms) < 0.022


# --- bad input ------------------------------------------------------------------------------
def test_bad_input(static_fit, subject, male50, gait):
    ms = static_fit.markerset
    walk = trial_of(ms.names, subject["walk"])
    other = trial_of(tuple(f"X{i}" for i in range(len(ms.names))), subject["walk"])
    with pytest.raises(ValueError, match="share no marker"), warnings.catch_warnings():
        warnings.simplefilter("ignore", MarkerWarning)
        fit_motion(static_fit.body, ms, other, start=static_fit.pose)
    bad = db.Pose(
        position=static_fit.pose.position.at[0].set(jnp.nan),
        angles=static_fit.pose.angles,
        spine_target=static_fit.pose.spine_target,
    )
    with pytest.raises(ValueError, match="start.position is not finite"):
        fit_motion(static_fit.body, ms, walk, start=bad)
    with pytest.raises(KeyError, match="Nope"):
        fit_motion(static_fit.body, ms, walk, start=static_fit.pose, weights={"Nope": 1.0})
    with pytest.raises(ValueError, match="at least one > 0"):
        fit_motion(
            static_fit.body, ms, walk, start=static_fit.pose, weights=np.zeros(len(ms.names))
        )
    with pytest.raises(ValueError, match="velocity must be True or False"):
        fit_motion(static_fit.body, ms, walk, start=static_fit.pose, velocity="on")
    static = trial_of(gait.names, subject["static_markers"][None])
    with pytest.raises(ValueError, match="not a choice"):
        scale_and_register(male50, static, gait, fit=("lengths", "width"))
    few = static.positions.copy()
    few[:, MIN_MARKERS - 1 :] = np.nan
    with pytest.raises(ValueError, match="cannot be placed"):
        scale_and_register(male50, trial_of(gait.names, few), gait, prior=False)


# --- the kernel -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def kernel(male50, gait):
    """The marker kernel as a function of (problem, lengths, offsets, posture), jacfwd and
    jacrev of it compiled once; a random posture (twists included) with random lengths and
    offsets."""
    lay = mocap_layout(male50, gait)

    def fast(problem, lengths, offsets, x):
        return tree_markers(lay, problem, lengths, offsets, x)

    pose = db.sample_pose(male50, jax.random.PRNGKey(0), spread=0.3)
    problem = make_problem(male50, lay.pose, pose)
    rng = np.random.default_rng(2)
    x = problem.x0 + 0.2 * rng.standard_normal(problem.x0.shape)
    lengths = male50.lengths * (1 + 0.1 * rng.uniform(size=male50.lengths.shape))
    offsets = gait.offsets + 0.01 * rng.standard_normal(gait.offsets.shape)
    argnums = (1, 2, 3)
    return {
        "lay": lay,
        "fast": jax.jit(fast),
        "jacfwd": jax.jit(jax.jacfwd(fast, argnums)),
        "jacrev": jax.jit(jax.jacrev(fast, argnums)),
        "args": (problem, lengths, offsets, x),
        "init": pose,
    }


def test_kernel_derivatives(kernel):
    """The closed-form derivatives of the marker kernel (lengths, offsets, posture): jacfwd
    equals jacrev and both match central differences along random directions."""
    problem, *args = kernel["args"]
    J_fwd = kernel["jacfwd"](problem, *args)
    J_rev = kernel["jacrev"](problem, *args)
    for a, b in zip(J_fwd, J_rev):
        np.testing.assert_allclose(a, b, atol=1e-12)
    rng = np.random.default_rng(9)
    h = 1e-6
    for _ in range(3):
        v = [rng.standard_normal(np.shape(a)) for a in args]
        up = kernel["fast"](problem, *(a + h * d for a, d in zip(args, v)))
        down = kernel["fast"](problem, *(a - h * d for a, d in zip(args, v)))
        directional = sum(np.tensordot(J, d, axes=d.ndim) for J, d in zip(J_fwd, v))
        np.testing.assert_allclose((up - down) / (2 * h), directional, atol=1e-7)


def test_kernel_equals_autodiff_through_the_walk(kernel):
    """The closed form against plain forward-mode autodiff through the walk (the kernel's
    fallback) along a random direction."""
    problem, *args = kernel["args"]
    rng = np.random.default_rng(1)
    v = tuple(jnp.asarray(rng.standard_normal(np.shape(a))) for a in args)

    def plain(lengths, offsets, x):
        return walk_points(problem, kernel["lay"].slots, lengths, offsets, offsets[:, 2], x)[0]

    # One program (op by op, the walk's hundreds of operations are a program each).
    _, tangent = jax.jit(lambda a, d: jax.jvp(plain, a, d))(tuple(args), v)
    J_fwd = kernel["jacfwd"](problem, *args)
    directional = sum(np.tensordot(J, d, axes=d.ndim) for J, d in zip(J_fwd, v))
    np.testing.assert_allclose(directional, tangent, atol=1e-12)


def test_kernel_places_the_markers_on_forward_frames(kernel, male50, gait):
    """Reference for the kernel's value: `db.forward` of the body with the kernel's lengths
    in the posture of x, each marker placed by hand on its segment (seed 000): its proximal
    joint plus the untwisted world frame applied to the offset turned about Z by the share
    clip(z / length, 0, 1) of the segment's twist, the twist read off forward's twisted
    frame. Random lengths (+0-10 %), offsets and a posture with twists: to rounding."""
    problem, lengths, offsets, x = kernel["args"]
    body = eqx.tree_at(lambda b: b.lengths, male50, lengths)
    fk = db.forward(body, problem.pose(x, kernel["init"]))
    seg = np.asarray(gait.segments)
    R_base = np.asarray(fk.R_world_base)[seg]
    R_base_twisted = np.einsum("kji,kjl->kil", R_base, np.asarray(fk.R_world_twisted)[seg])
    tau = np.arctan2(R_base_twisted[:, 1, 0], R_base_twisted[:, 0, 0])
    o = np.asarray(offsets)
    turn = tau * np.clip(o[:, 2] / np.asarray(lengths)[seg], 0.0, 1.0)
    c, s = np.cos(turn), np.sin(turn)
    turned = np.stack([c * o[:, 0] - s * o[:, 1], s * o[:, 0] + c * o[:, 1], o[:, 2]], -1)
    proximal = np.asarray(fk.joint_positions)[np.asarray(male50.proximal_joint)[seg]]
    expected = proximal + np.einsum("kij,kj->ki", R_base, turned)
    assert np.abs(tau).max() > 0.1  # the twists take part
    np.testing.assert_allclose(kernel["fast"](problem, lengths, offsets, x), expected, atol=1e-12)


def test_kernel_gradients_are_finite_at_the_standard_position(kernel, male50, gait):
    """At the standard position the limbs hang at their sockets' poles and the knees and
    elbows sit at their stops: the Jacobian is finite."""
    problem = make_problem(male50, kernel["lay"].pose, male50.rest_pose())
    J = kernel["jacfwd"](problem, male50.lengths, gait.offsets, problem.x0)
    assert all(np.all(np.isfinite(a)) for a in J) and np.any(J[2] != 0)


def test_lean_layout(male50, gait):
    """Only marked segments and those above them move: no hand is walked."""
    lay = mocap_layout(male50, gait)
    walked = {male50.segment_names[s] for s in lay.pose.chain.segments}
    assert "left_hand" not in walked and "right_hand" not in walked
    assert {"head", "left_forearm", "right_foot", "T6"} <= walked


@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), st.floats(0.0, 3.1))
def test_rotation_vector_inverts_exp(axis, angle):
    a = np.asarray(axis)
    if np.linalg.norm(a) < 1e-3:
        a = np.array([0.0, 0.0, 1.0])
    v = angle * a / np.linalg.norm(a)
    np.testing.assert_allclose(rotation_vector(exp_rotvec(jnp.asarray(v))), v, atol=1e-9)


def test_rigid_fit_recovers_a_rigid_motion():
    rng = np.random.default_rng(4)
    a = rng.standard_normal((6, 3))
    R = np.asarray(exp_rotvec(jnp.asarray([0.3, -2.0, 1.1])))
    t = np.array([0.5, -0.2, 1.0])
    w = np.array([1.0, 2.0, 1.0, 0.5, 0.0, 1.0])
    R_fit, t_fit = rigid_fit(jnp.asarray(a), jnp.asarray(a @ R.T + t), jnp.asarray(w))
    np.testing.assert_allclose(R_fit, R, atol=1e-12)
    np.testing.assert_allclose(t_fit, t, atol=1e-12)
    R0, t0 = rigid_fit(jnp.asarray(a), jnp.asarray(a), jnp.zeros(6))
    np.testing.assert_array_equal(R0, np.eye(3))


# --- descriptors ----------------------------------------------------------------------------
def _swinging(male50, n=21) -> db.Pose:
    """A left leg swinging from flexion through the hanging direction into extension, 0.3
    degrees beside its pole, and a left arm raised overhead and moved across through the
    vertical: each passes by its socket's pole (the hanging leg at phi = pi, the raised arm
    at phi = 0)."""
    rest = male50.rest_pose()
    s = np.deg2rad(np.linspace(-25.0, 25.0, n))
    eps = np.deg2rad(0.3)
    leg = np.stack([np.sin(s), np.full(n, eps), -np.cos(s)], -1)  # socket frame
    arm = np.stack([np.full(n, eps), np.sin(s), np.cos(s)], -1)
    angles = np.repeat(np.asarray(rest.angles)[None], n, axis=0)
    for name, d in (("left_thigh", leg), ("left_upper_arm", arm)):
        theta, phi, _ = db.vector_to_azimuth_polar(jnp.asarray(d))
        angles[:, male50.segment_index(name), :2] = np.stack([theta, phi], -1)
    return jax.vmap(lambda a: db.Pose(position=rest.position, angles=a))(jnp.asarray(angles))


def test_descriptors_do_not_flip_near_the_poles(male50):
    """A smooth motion past the poles: frame to frame no descriptor moves by more than 30
    degrees, and r is each bone's length."""
    poses = _swinging(male50)
    d = descriptors(male50, poses)
    names = d["names"]
    assert d["seed001"].shape == d["angles"].shape == (21, male50.n_segments - 1, 3)
    for key in ("seed001", "angles"):
        jumps = np.abs(np.diff(d[key][..., :2], axis=0))
        assert np.degrees(jumps.max()) < 30.0, key
    # Read frame by frame, the arm's azimuth swings by 180 degrees within two frames.
    raw = np.degrees(np.asarray(poses.angles)[:, male50.segment_index("left_upper_arm"), 0])
    assert np.abs(np.diff(raw)).max() > 60.0 and raw.max() - raw.min() > 170.0
    np.testing.assert_allclose(
        d["seed001"][..., 2], np.broadcast_to(np.asarray(male50.lengths)[1:], (21, len(names)))
    )


def test_unwrap_holds_the_azimuth_at_the_pole():
    """Straight through the pole: the azimuth is held there, the polar angle continues past
    it (to negative values) instead of folding back."""
    polar = np.abs(np.linspace(-0.5, 0.5, 11))
    azimuth = np.where(np.linspace(-0.5, 0.5, 11) < 0, np.pi + 0.2, 0.2)
    azimuth[5] = 1.234  # undefined at the pole
    a, p = unwrap_directions(azimuth, polar)
    np.testing.assert_allclose(a, np.pi + 0.2)
    np.testing.assert_allclose(p, np.linspace(0.5, -0.5, 11), atol=1e-12)


# --- the robust loss and the motion limits ----------------------------------------------------
@given(st.floats(0.0, 0.5), st.floats(0.005, 0.1))
def test_robust_rows_sum_to_cauchys_loss(d, c):
    """A marker's rows square-sum to c^2 log(1 + d^2 / c^2) (closed form) for weight 1,
    in float64, also across the series switch near d = 0."""
    with jax.enable_x64(True):
        rows = jnp.array([[d, 0.0, 0.0]])
        out = robust_rows(rows, jnp.array([d * d]), jnp.asarray(c))
        assert np.isclose(float(jnp.sum(out**2)), c * c * np.log1p(d * d / (c * c)), rtol=1e-7)


def test_robust_rows_derivatives():
    """jacfwd = jacrev = central finite differences of the rows in a marker's error, and
    finite (identity) at zero error."""
    with jax.enable_x64(True):

        def f(e):
            return robust_rows(e[None], jnp.sum(e * e)[None], 0.03)[0]

        e = jnp.array([0.02, -0.05, 0.01])
        J = jax.jacfwd(f)(e)
        np.testing.assert_allclose(J, jax.jacrev(f)(e), rtol=1e-10)
        h = 1e-6
        fd = np.stack([(f(e + h * u) - f(e - h * u)) / (2 * h) for u in np.eye(3)], axis=1)
        np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(jax.jacfwd(f)(jnp.zeros(3)), np.eye(3), atol=1e-12)


def test_motion_limits(male50):
    """Idempotent; each side's intervals the other's mirror (swing_x and the twist negated
    and swapped); the hip's extension 30 degrees (38 CFR 4.71), past the default's 15; the
    spine untouched; a hinge keeps w_x = 0."""
    b = motion_limits(male50)
    again = motion_limits(b)
    for field in ("swing_lo", "swing_hi", "swing_max", "twist_lo", "twist_hi"):
        np.testing.assert_array_equal(getattr(again, field), getattr(b, field))
    for part in MOTION_RANGES:
        left, right = b.segment_index(f"left_{part}"), b.segment_index(f"right_{part}")
        np.testing.assert_allclose(b.swing_lo[left, 1], b.swing_lo[right, 1])
        np.testing.assert_allclose(b.swing_lo[left, 0], -b.swing_hi[right, 0])
        np.testing.assert_allclose(b.twist_lo[left], -b.twist_hi[right])
    thigh = b.segment_index("left_thigh")
    assert np.isclose(np.degrees(float(b.swing_lo[thigh, 1])), -30.0, atol=1e-4)
    assert float(male50.swing_lo[thigh, 1]) > float(b.swing_lo[thigh, 1])
    shank = b.segment_index("left_shank")
    assert float(b.swing_lo[shank, 0]) == float(male50.swing_lo[shank, 0])
    spine = [i for i, n in enumerate(b.segment_names) if n[0] in "LTC" and n[1:].isdigit()]
    np.testing.assert_array_equal(np.asarray(b.swing_lo)[spine], np.asarray(male50.swing_lo)[spine])


def test_the_rest_start_is_the_rest_pose_in_a_fitted_pose_s_structure(male50, static_fit):
    """A regression: the registration built its problem from the rest pose (no spine
    target) and the motion fit from the fitted pose (a spine target): two compiled
    `make_problem`s (0.8 s). `rest_start` names the rest angles' total as the spine target:
    the structure of a fitted pose, and the same problem as the rest pose (reference: the
    problem of the rest pose itself, to rounding)."""
    from diffbody.mocap._mocap_solver import make_problem_jit, rest_start
    from diffbody.problem._problem import make_problem

    fitted = static_fit.pose
    start = rest_start(male50)
    assert jax.tree.structure(start) == jax.tree.structure(fitted)
    markerset = load_markerset("opensim-gait", male50)
    lay = mocap_layout(male50, markerset)
    ours = make_problem_jit(male50, lay.pose, start)
    plain = make_problem(male50, lay.pose, male50.rest_pose())
    np.testing.assert_allclose(ours.x0, plain.x0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.R_socket0, plain.R_socket0, rtol=0, atol=1e-9)
