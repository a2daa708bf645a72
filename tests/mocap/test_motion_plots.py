"""The motion fit's plot: its lines are the joint angles and the marker errors, computed
here independently."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody._solver import FitStatus
from diffbody.mocap._motion_plots import draw_motion, joint_groups
from diffbody.mocap._motion_result import MotionFit, rms_max

N = 6  # frames


@pytest.fixture(scope="module")
def fit(male50) -> MotionFit:
    """A MotionFit as fit_motion returns it, of a knee and hip swinging through 6 frames
    (0.1 s apart), with made-up marker errors: a marker missing in frames 2 and 3, a frame
    whose fit failed (every marker missing)."""
    rest = male50.rest_pose()
    thigh, shank = male50.segment_index("right_thigh"), male50.segment_index("right_shank")
    frames = []
    for a in np.linspace(0.0, 0.8, N):
        angles = rest.angles.at[thigh, 1].add(0.5 * a).at[shank, 1].add(a)
        frames.append(db.Pose(rest.position, angles))
    poses = jax.tree.map(lambda *x: jnp.stack(x), *frames)
    rng = np.random.default_rng(0)
    errors = rng.uniform(0.002, 0.02, (N, 4))
    errors[2:4, 1] = np.nan
    errors[5] = np.nan
    rms, worst = rms_max(errors, axis=1)
    status = np.full(N, int(FitStatus.CONVERGED))
    status[5] = FitStatus.FAILED
    return MotionFit(
        poses=poses,
        markers=np.zeros((N, 4, 3)),
        errors=errors,
        rms=rms,
        max=worst,
        status=status,
        steps=np.ones(N, int),
        times=0.1 * np.arange(N),
        outliers=np.zeros((N, 4), bool),
        scale=0.02,
        names=("A", "B", "C", "D"),
        kinds=("anatomical",) * 4,
    )


def test_draw_motion_lines(male50, fit, tmp_path):
    png = tmp_path / "motion.png"
    fig = draw_motion(fit, male50, title="six frames", path=png)
    groups = joint_groups()
    assert [g[0] for g in groups] == [
        "hip, right", "hip, left", "knee, right", "knee, left", "ankle, right", "ankle, left",
    ]  # fmt: skip
    axes = fig.axes
    assert len(axes) == len(groups) + 1
    # The angles: each frame's joint_angles, computed one pose at a time.
    one = jax.jit(lambda pose: db.joint_angles(male50, pose))
    expected = [one(jax.tree.map(lambda a: a[i], fit.poses)) for i in range(N)]
    for ax, (label, names) in zip(axes, groups):
        assert ax.get_title(loc="left") == label
        lines = ax.get_lines()[: len(names)]
        motions = {"hip": "flexion", "knee": "flexion", "ankle": "dorsiflexion"}
        second = {"hip": "adduction", "knee": "adduction", "ankle": "inversion"}
        joint = label.split(",")[0]
        assert [ln.get_label() for ln in lines] == [motions[joint], second[joint], "rotation"]
        for line, name in zip(lines, names):
            np.testing.assert_allclose(line.get_xdata(), fit.times)
            np.testing.assert_allclose(
                line.get_ydata(), [float(e[name]) for e in expected], atol=1e-9
            )
    knee = np.asarray(axes[2].get_lines()[0].get_ydata())
    assert knee[-1] > 30 and np.all(np.diff(knee) > 0)  # the right knee bends, frame by frame
    # The marker errors, mm: RMS over the markers each frame sees, the largest of them.
    rms, largest, failed = axes[-1].get_lines()[:3]
    seen = np.isfinite(fit.errors)
    expect = [
        1000 * np.sqrt(np.mean(e[s] ** 2)) if s.any() else np.nan for e, s in zip(fit.errors, seen)
    ]
    np.testing.assert_allclose(rms.get_ydata(), expect, atol=1e-9)
    np.testing.assert_allclose(largest.get_ydata()[:5], 1000 * np.nanmax(fit.errors[:5], axis=1))
    assert failed.get_label() == "fit failed" and list(failed.get_xdata()) == [fit.times[5]]
    assert axes[-1].get_ylabel() == "mm"
    assert png.stat().st_size > 10_000


def test_draw_motion_joints(male50, fit):
    import matplotlib.figure

    fig = matplotlib.figure.Figure()
    draw_motion(fit, male50, joints=("knee", "lumbar"), fig=fig)
    titles = [ax.get_title(loc="left") for ax in fig.axes]
    assert titles == ["knee, right", "knee, left", "lumbar", "marker error per frame"]
    with pytest.raises(ValueError, match="unknown joint 'wrist'"):
        draw_motion(fit, male50, joints=("wrist",))
