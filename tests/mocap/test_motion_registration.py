"""Registration from the motion as well as the static trial (diffbody.mocap:
_motion_registration, `scale_and_register(motion=)`): the frames it picks, its answer on the
shipped walk against the static trial's alone, and its refusals."""

import warnings

import jax
import numpy as np
import pytest

import diffbody as db
from diffbody.anthropometry._scaling import SCALE_GROUPS
from diffbody.clouds._cloud_fit import FitStatus
from diffbody.files._data_files import data_file
from diffbody.files._marker_trial import MarkerTrial
from diffbody.mocap._markerset import MarkerWarning
from diffbody.mocap._mocap_solver import MIN_MARKERS
from diffbody.mocap._motion_registration import MOTION_FRAMES, sample_frames

CLAVICLE = list(SCALE_GROUPS).index("clavicle")


def _trial(names, positions, source="synthetic") -> MarkerTrial:
    n = len(positions)
    return MarkerTrial(names, np.arange(n) / 100.0, positions, 100.0, source)


# --- the frames -------------------------------------------------------------------------------
def test_frames_spread_evenly_in_the_sets_order():
    """k frames spread over every frame that sees `MIN_MARKERS` of the set's markers, in the
    set's marker order: a marker the trial lacks, or a dead one, is NaN; over two trials
    the frames run on from the first into the second."""
    gait = db.load_markerset("opensim-gait", db.load_body(variant="male50"))
    names = gait.names[:5]
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 5, 3))
    a[:, 4] = 0.5  # still while the others move: dead ("does not move")
    a[10:20, :3] = np.nan  # 10 frames that see 1 marker (2 with the dead one)
    b = rng.normal(size=(9, 4, 3))
    first = _trial(names[::-1], a[:, ::-1], "a.trc")  # another marker order
    second = _trial(names[:4], b, "b.trc")  # lacks the fifth marker
    sampled, where = sample_frames(gait, [first, second], 5)
    # 29 frames qualify (a's 0-9 and 20-29, b's 0-8): the 0th, 7th, 14th, 21st and 28th.
    assert where == ((0, 0), (0, 7), (0, 24), (1, 1), (1, 8))
    assert sampled.names == gait.names and sampled.n_frames == 5
    np.testing.assert_array_equal(sampled.positions[0, :4], a[0, :4])
    np.testing.assert_array_equal(sampled.positions[2, :4], a[24, :4])
    assert np.all(np.isnan(sampled.positions[:, 4]))
    np.testing.assert_array_equal(sampled.positions[3, :4], b[1])
    assert np.all(np.isnan(sampled.positions[:, 5:]))
    # Fewer frames than asked: all of them, once each.
    assert len(sample_frames(gait, second, 50)[1]) == 9


def test_frames_refuse_what_cannot_register():
    gait = db.load_markerset("opensim-gait", db.load_body(variant="male50"))
    blind = _trial(gait.names[: MIN_MARKERS - 1], np.zeros((4, MIN_MARKERS - 1, 3)), "few.trc")
    with pytest.raises(ValueError, match=r"'few.trc'.*motion_frames=0"):
        sample_frames(gait, blind, 4)
    with pytest.raises(TypeError, match="MarkerTrial"):
        sample_frames(gait, "walk.trc", 4)


@pytest.mark.parametrize("k", [-1, 2.5, True, "8"])
def test_motion_frames_must_be_a_count(k):
    body = db.load_body(variant="male50")
    static = db.read_trc(data_file("mocap/subject01_static.trc"))
    gait = db.load_markerset("opensim-gait", body)
    with pytest.raises(ValueError, match="motion_frames must be an integer >= 0"):
        db.scale_and_register(body, static, gait, motion=static, motion_frames=k)


# --- the shipped walk -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def registered():
    """The README's workflow on the shipped walk in float32, registered on the static trial
    and `MOTION_FRAMES` of the walk: the registration and the walk's fit. (On the static
    trial alone: tests/mocap/test_mocap.py, `shipped`.)"""
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.simplefilter("ignore", MarkerWarning)
        body = db.load_body(variant="male50")
        static = db.read_trc(data_file("mocap/subject01_static.trc"))
        walk = db.read_trc(data_file("mocap/subject01_walk1.trc"))
        gait = db.load_markerset("opensim-gait", body)
        fit = db.scale_and_register(body, static, gait, motion=walk)
        ms = fit.markerset.select(walk.names)
        return fit, db.fit_motion(fit.body, ms, walk, start=fit.pose, scale=fit.marker_scale)


def test_the_walk_shows_the_shoulders_the_static_trial_hides(registered):
    """On the shipped walk the static trial alone registers the arms' markers in its T-pose
    and the walk's mean marker RMS is 18.7 mm (tests/mocap/test_mocap.py); registered on 8 of
    the walk's frames as well it is 7.3 mm (AddBiomechanics' published figure is about 15
    mm), every frame converged. The clavicles take the shoulder width the walk shows
    (acromia 419 mm apart, against 342 mm in the T-pose): their scale factor is 0.97, where
    the static trial alone gives 0.89. The static trial's markers stay within 6 cm (the
    acromia, 5.3 cm, are where the T-pose differs)."""
    fit, walk = registered
    assert int(fit.status) == FitStatus.CONVERGED
    assert len(fit.motion_frames) == MOTION_FRAMES
    frames = [f for _, f in fit.motion_frames]
    assert frames[0] == 0 and frames[-1] == 150 and np.all(np.diff(frames) >= 20)
    assert fit.motion_errors.shape == (MOTION_FRAMES, len(fit.markerset.names))
    assert np.mean(walk.rms) < 0.009 and np.all(walk.status == FitStatus.CONVERGED)
    assert float(fit.axial[CLAVICLE]) > 0.94
    assert np.nanmax(np.asarray(fit.errors)) < 0.06
    # The registration's own frames: within 1.5 cm RMS each (6.5-12.4 mm; the walk's fit,
    # each frame from its neighbour, takes them on to 6.5-9.7 mm).
    names = list(fit.markerset.names)
    cols = [names.index(n) for n in walk.names]
    e = np.asarray(fit.motion_errors)[:, cols]
    assert np.all(np.sqrt(np.nanmean(e**2, axis=1)) < 0.015)
    # Dimensions a person has: each axial factor within the population's plausible range.
    axial = np.asarray(fit.axial)
    assert np.all((axial > 0.8) & (axial < 1.4)), dict(zip(SCALE_GROUPS, axial.round(3)))


def test_the_walks_joint_angles_do_not_jump(registered):
    """Registered on the walk too, every ISB joint angle of the shipped walk moves at most 10
    degrees from one frame to the next (600 deg/s at 60 Hz: above the knee's swing, about 8.8
    deg the largest measured, the right ankle's inversion). Registered on the static trial
    alone, the left arm switched between two postures between frames 100 and 101 (the arm's
    rotation by 83 degrees, the elbow by 44) as its badly registered markers drifted: a jump
    the markers do not show."""
    fit, walk = registered
    with jax.enable_x64(False):
        angles = walk.angles(fit.body)
    steps = {n: np.abs(np.diff(np.rad2deg(np.unwrap(np.deg2rad(v))))) for n, v in angles.items()}
    worst = max(steps, key=lambda n: steps[n].max())
    assert steps[worst].max() < 10.0, (worst, int(steps[worst].argmax()), steps[worst].max())
