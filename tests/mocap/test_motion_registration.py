"""Registration from the motion as well as the static trial (diffbody.mocap:
_motion_registration, `scale_and_register(motion=)`): the frames it picks and its refusals.
Its answer on the shipped walk: tests/mocap/test_mocap.py (`shipped`, the README's
workflow)."""

import numpy as np
import pytest

import diffbody as db
from diffbody.files._data_files import data_file
from diffbody.files._marker_trial import MarkerTrial
from diffbody.mocap._mocap_solver import MIN_MARKERS
from diffbody.mocap._motion_registration import sample_frames


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
