"""The grades against OpenSim's best practices (`diffbody.mocap._grades`), on fits whose
errors are known: each threshold met just under its limit and broken just over it, and what
breaks it named, worst first."""

from types import SimpleNamespace

import numpy as np
import pytest

from diffbody.mocap._grades import IK_MAX, IK_RMS, SCALE_MAX, SCALE_RMS, grade_motion, grade_static

NAMES = ("A", "B", "C", "D")
KINDS = ("anatomical", "anatomical", "tracking", "tracking")


def _static(errors):
    markerset = SimpleNamespace(names=NAMES, kinds=KINDS)
    return SimpleNamespace(markerset=markerset, errors=np.asarray(errors, float))


def _motion(errors):
    e = np.asarray(errors, float)
    rms = np.sqrt(np.nanmean(e**2, axis=1))
    return SimpleNamespace(errors=e, names=NAMES, kinds=KINDS, rms=rms, max=np.nanmax(e, axis=1))


@pytest.mark.parametrize("factor, met", [(0.99, True), (1.01, False)])
def test_the_static_thresholds(factor, met):
    """Both bony landmarks at the RMS limit times `factor`: met under it; one landmark over
    the 2 cm limit is named with its error; the tracking markers do not count."""
    rms, largest = grade_static(_static([factor * SCALE_RMS] * 2 + [1.0, 1.0]))
    assert rms.met is met and rms.value == pytest.approx(factor * SCALE_RMS)
    assert largest.met and not largest.breaks
    _, largest = grade_static(_static([0.5 * SCALE_RMS, 1.5 * SCALE_MAX, 1.0, 1.0]))
    assert not largest.met and largest.breaks == (("B", pytest.approx(1.5 * SCALE_MAX)),)


def test_the_frames_and_the_classes():
    """Three frames: one clean, one with a marker past 4 cm (named, in a third of the frames),
    one missing a marker (NaN takes no part); the tracking class over its RMS limit."""
    low = 0.5 * IK_RMS
    errors = [
        [low, low, low, low],
        [low, 1.1 * IK_MAX, low, low],
        [low, np.nan, low, low],
    ]
    anatomical, tracking, frames = grade_motion(_motion(errors))
    assert tracking.met and tracking.value == pytest.approx(low)
    assert not anatomical.met  # the 4.4 cm marker lifts the class's RMS over 2 cm
    assert frames.value == pytest.approx(2 / 3) and not frames.met
    assert frames.breaks == (("B", pytest.approx(1 / 2)),)  # of the two frames that see B
    assert "not met; worst: B in 50 % of frames" in frames.line()
    clean = grade_motion(_motion([[low] * 4] * 3))
    assert all(g.met for g in clean) and clean[-1].line().endswith("met")
