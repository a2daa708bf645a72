"""The image-sequence plots: their lines are the bounds, lengths and reprojection errors,
computed here independently."""

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402

import diffbody as db  # noqa: E402
from diffbody.images._sequence_plots import (  # noqa: E402
    draw_bounds,
    draw_sequence_fit,
    reprojection_errors,
)

T, FOCAL = 12, 800.0


def _sequence(tree):
    """Joints (T, J, 3) m 3-5 m in front of the camera, their images with 1 px of noise
    (5 px in frame 7), Webb-like bounds rising to the lengths."""
    rng = np.random.default_rng(1)
    joints = rng.uniform(-0.8, 0.8, (T, tree.n_joints, 3)) + np.array([0.0, 0.0, 4.0])
    uv = FOCAL * joints[..., :2] / joints[..., 2:] + rng.normal(0, 1.0, (T, tree.n_joints, 2))
    uv[7] += rng.normal(0, 5.0, (tree.n_joints, 2))
    lengths = rng.uniform(0.1, 0.5, tree.n_parts)
    bounds = np.maximum.accumulate(rng.uniform(0.5, 1.0, (T, tree.n_parts)), axis=0) * lengths
    return joints, uv, bounds, lengths


def test_reprojection_errors_per_frame():
    tree = db.images.default_joint_tree()
    joints, uv, _, _ = _sequence(tree)
    errors = reprojection_errors(uv, joints, FOCAL)
    for t in range(T):
        d = [
            np.hypot(FOCAL * x / z - u, FOCAL * y / z - v)
            for (x, y, z), (u, v) in zip(joints[t], uv[t])
        ]
        assert np.isclose(errors[t], np.sqrt(np.mean(np.square(d))))
    # Their RMS over the frames is Lifting.reprojection_rms's: over every joint and frame.
    projected = FOCAL * joints[..., :2] / joints[..., 2:]
    overall = np.sqrt(np.mean(np.sum((projected - uv) ** 2, axis=-1)))
    assert np.isclose(np.sqrt(np.mean(errors**2)), overall)
    assert np.argmax(errors) == 7


def test_draw_sequence_fit(tmp_path):
    tree = db.images.default_joint_tree()
    joints, uv, bounds, lengths = _sequence(tree)
    png = tmp_path / "sequence.png"
    fig = draw_sequence_fit(
        tree, bounds, uv, joints, FOCAL, lengths=lengths, title="twelve frames", path=png
    )
    top, bottom = fig.axes
    lines = top.get_lines()
    P = tree.n_parts
    # Per part: its bounds over the frames, then its final length dashed at the right.
    for k in range(P):
        bound, final = lines[2 * k], lines[2 * k + 1]
        np.testing.assert_array_equal(bound.get_ydata(), bounds[:, k])
        assert bound.get_label() == tree.part_names[k].split("->")[1]
        np.testing.assert_array_equal(final.get_ydata(), [lengths[k]] * 2)
        assert final.get_linestyle() == "--" and final.get_xdata()[1] > T - 1
    assert "dashed: final" in top.get_legend().get_title().get_text()
    per_frame, rms = bottom.get_lines()
    np.testing.assert_allclose(per_frame.get_ydata(), reprojection_errors(uv, joints, FOCAL))
    assert np.isclose(rms.get_ydata()[0], np.sqrt(np.mean(per_frame.get_ydata() ** 2)))
    assert bottom.get_ylabel() == "reprojection error (px)"
    assert png.stat().st_size > 10_000


def test_draw_bounds_alone(tmp_path):
    """Without final lengths: one line per part, the true lengths dotted."""
    tree = db.images.default_joint_tree()
    _, _, bounds, lengths = _sequence(tree)
    fig = draw_bounds(tree, bounds, true_lengths=lengths, path=tmp_path / "bounds.png")
    lines = fig.axes[0].get_lines()
    assert len(lines) == 2 * tree.n_parts
    assert [ln.get_linestyle() for ln in lines[1::2]] == [":"] * tree.n_parts
    assert (tmp_path / "bounds.png").is_file()
