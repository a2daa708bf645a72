"""The viewer's scene (every frame's spheres, angles and overlays) and its server, without a
browser."""

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffbody as db
from diffbody._joint_angles import angle_names, joint_angles
from diffbody.viewer import build_scene, view
from diffbody.viewer._viewer import angle_table


@pytest.fixture(scope="module")
def record(male50, arm_raise, tmp_path_factory):
    """The sequence read back from a pose file with every overlay: markers with a gap, a
    cloud with an outlier and a target."""
    poses, times = arm_raise
    markers = np.tile([[0.1, 0.2, 1.0], [0.2, -0.2, 1.1]], (len(times), 1, 1))
    markers[2, 1] = np.nan
    overlays = {
        "markers": {"names": ["a", "b"], "positions": markers},
        "cloud": {
            "centers": [[0.0, 0.0, 1.0], [0.5, 0.5, 0.5]],
            "radii": [0.1, 0.05],
            "inliers": [True, False],
        },
        "targets": {"names": ["left_hand.palm"], "points": [[0.5, 0.3, 1.5]]},
    }
    path = tmp_path_factory.mktemp("view") / "swing.pose.json"
    db.save_pose(path, male50, poses, times=times, overlays=overlays)
    return db.load_pose(path, male50)


@pytest.fixture(scope="module")
def scene(male50, record):
    return build_scene(male50, record)


def test_each_frame_is_the_forward_kinematics_of_its_pose(fk_male50, record, scene):
    assert scene.n_frames == record.n_frames == 5 and scene.kind == "sequence"
    np.testing.assert_allclose(scene.times, record.times)
    for k in range(record.n_frames):
        fk = fk_male50(record.frame(k))
        np.testing.assert_allclose(scene.centers[k], fk.sphere_centers, atol=1e-12)
        np.testing.assert_allclose(scene.radii[k], fk.sphere_radii, atol=1e-12)
    # The arms move between frames: the slider has something to show.
    assert np.abs(scene.centers[-1] - scene.centers[0]).max() > 0.5


def test_panel_shows_the_joint_angles_of_each_frame(male50, record, scene):
    assert scene.angle_names == angle_names()
    expected = joint_angles(male50, record.frame(3))
    np.testing.assert_allclose(
        scene.angles_deg[3], [float(expected[n]) for n in angle_names()], atol=1e-9
    )
    i = scene.angle_names.index("arm_flex_r")
    assert scene.angles_deg[0, i] == pytest.approx(0.0, abs=1e-6)
    assert scene.angles_deg[-1, i] == pytest.approx(120.0, abs=1e-6)


def test_overlays_of_the_pose_file_are_drawn(scene):
    assert scene.markers.shape == (5, 2, 3) and np.isnan(scene.markers[2, 1]).all()
    centers, radii, inliers = scene.cloud
    assert centers.shape == (2, 3) and list(inliers) == [True, False]
    np.testing.assert_allclose(scene.targets, np.tile([[0.5, 0.3, 1.5]], (5, 1, 1)))


def test_one_pose_and_given_overlays(male50):
    scene = build_scene(male50, male50.rest_pose(), markers=[[0.0, 0.0, 1.0]], cloud=None)
    assert scene.kind == "pose" and scene.centers.shape == (1, male50.n_spheres, 3)
    assert scene.markers.shape == (1, 1, 3) and scene.cloud is None and scene.targets is None
    with pytest.raises(ValueError, match="markers of shape"):
        build_scene(male50, male50.rest_pose(), markers=np.zeros((2, 1, 3)))


def test_angle_table_pairs_the_sides():
    table = angle_table(("knee_angle_r", "knee_angle_l", "lumbar_bending"), np.array([1, -2e-9, 3]))
    lines = table.splitlines()
    assert lines[0] == "| | right | left |"
    assert "| knee_angle | 1.0 | 0.0 |" in lines and "| lumbar_bending | 3.0 |  |" in lines
    table = angle_table(("head.theta", "head.phi", "head.tau"), np.array([1.0, 2.0, 3.0]))
    assert table.splitlines()[-1] == "| head | 1.0 | 2.0 | 3.0 |"


def test_without_viser_the_message_says_what_to_install(male50, monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser raises ImportError
    with pytest.raises(ImportError, match=r"pip install 'diffbody\[view\]'"):
        view(male50, male50.rest_pose())


def test_served_scene_follows_the_frame(male50, record, scene):
    pytest.importorskip("viser", reason="the viewer needs viser: pip install 'diffbody[view]'")
    with view(male50, record, port=0) as viewer:
        assert viewer.url.startswith("http://127.0.0.1:") and viewer.n_frames == 5
        assert set(viewer.overlays) == {"markers", "cloud", "targets"}
        for k in (4, 2):
            viewer.set_frame(k)
            assert viewer.frame == k and viewer._slider.value == k
            np.testing.assert_allclose(viewer._body.batched_positions, scene.centers[k], atol=1e-6)
            np.testing.assert_allclose(viewer._body.batched_scales, scene.radii[k], atol=1e-6)
        # Frame 2 lacks marker b: drawn with scale 0.
        np.testing.assert_allclose(viewer.overlays["markers"].batched_scales, [0.012, 0.0])
        # The GUI slider moves the body as set_frame does.
        viewer._slider.value = 0
        np.testing.assert_allclose(viewer._body.batched_positions, scene.centers[0], atol=1e-6)
        with pytest.raises(IndexError, match="frame 5 of 5"):
            viewer.set_frame(5)


def test_a_batch_shows_each_rows_targets(male50):
    """The batch command's postures carry one target per row (n, k, 3): the scene keeps
    them per frame (regression: it refused them)."""
    poses = jax.tree.map(lambda a: jnp.stack([a, a, a]), male50.rest_pose())
    points = np.arange(9.0).reshape(3, 1, 3)
    scene = build_scene(male50, poses, targets={"names": ["left_hand.palm"], "points": points})
    assert scene.kind == "batch"
    np.testing.assert_array_equal(scene.targets, points)
    with pytest.raises(ValueError, match="targets of shape"):
        build_scene(male50, poses, targets=np.zeros((2, 1, 3)))
