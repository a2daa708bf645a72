"""The pose file (diffbody.files._pose_file): round trips of a pose, a sequence and a batch in
both containers, the structure check with its message, bad files, and `render --pose`."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bodies import mini_doc, write
from command_line import ARM_BATCH, arm_batch, fails
from hypothesis import given
from hypothesis import strategies as st

import diffbody as db
from diffbody.cli import main
from diffbody.files import PoseFileError, structure_hash

_SAMPLERS: dict = {}


def _poses(body, n: int, seed: int = 0) -> db.Pose:
    """n sampled poses; one compiled sampler per body (`sample_pose` reads the body's limits
    on the host, so the body is closed over, not traced)."""
    if id(body) not in _SAMPLERS:
        sample = jax.vmap(lambda k: db.sample_pose(body, k, spread=0.5))
        _SAMPLERS[id(body)] = (body, jax.jit(sample))
    return _SAMPLERS[id(body)][1](jax.random.split(jax.random.PRNGKey(seed), n))


def _same(a: db.Pose, b: db.Pose) -> None:
    np.testing.assert_allclose(a.angles, b.angles, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.position, b.position, rtol=0, atol=1e-15)
    assert (a.spine_target is None) == (b.spine_target is None)
    if a.spine_target is not None:
        np.testing.assert_allclose(a.spine_target, b.spine_target, rtol=0, atol=1e-12)


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_a_sequence_round_trips(male50, tmp_path, suffix):
    """Angles to 1e-12 rad through degrees, times, statuses, residuals and overlays as saved;
    an .npz moves its large arrays out of the JSON document."""
    poses = _poses(male50, 50)
    poses = jax.vmap(lambda p: db.Pose(p.position, p.angles, 0.1 * p.angles[0]))(poses)
    times = np.arange(50) / 60.0
    markers = np.random.default_rng(0).normal(size=(50, 41, 3))
    markers[3, 7] = np.nan  # a gap
    path = db.save_pose(
        tmp_path / f"walk{suffix}",
        male50,
        poses,
        times=times,
        status=["converged"] * 49 + ["failed"],
        residuals={"rms": np.linspace(0, 0.01, 50)},
        overlays={"markers": {"names": [f"M{i}" for i in range(41)], "positions": markers}},
        extra={"trial": "walk.trc"},
    )
    record = db.load_pose(path, male50)
    assert record.kind == "sequence" and record.n_frames == 50 and record.body_name == "male50"
    _same(record.pose, poses)
    np.testing.assert_array_equal(record.times, times)
    assert record.status[-1] == "failed" and len(record.status) == 50
    np.testing.assert_array_equal(record.residuals["rms"], np.linspace(0, 0.01, 50))
    np.testing.assert_array_equal(record.overlays["markers"]["positions"], markers)
    assert record.extra == {"trial": "walk.trc"}
    _same(record.frame(7), db.Pose(poses.position[7], poses.angles[7], poses.spine_target[7]))
    if suffix == ".npz":
        document = json.loads(str(np.load(path)["document"]))
        assert document["overlays"]["markers"]["positions"] == {"npz": "overlays/markers/positions"}


@given(seed=st.integers(0, 2**16), batch=st.booleans())
def test_poses_round_trip(male50, tmp_path_factory, seed, batch):
    """Any sampled pose or batch of poses reads back as written (JSON)."""
    path = tmp_path_factory.mktemp("poses") / "p.json"
    poses = _poses(male50, 3, seed)
    pose = poses if batch else db.Pose(poses.position[0], poses.angles[0])
    record = db.load_pose(db.save_pose(path, male50, pose), male50)
    assert record.kind == ("batch" if batch else "pose")
    _same(record.pose, pose)


def test_a_pose_loads_onto_a_body_of_the_same_structure(male50, female50, tmp_path):
    """The file names the body and its structure; another body of the same tree (female50,
    a scaled one) reads it, with the same angles."""
    pose = _poses(male50, 1).angles[0]
    path = db.save_pose(tmp_path / "p.json", male50, db.Pose(jnp.zeros(3), pose))
    assert structure_hash(male50) == structure_hash(female50)
    record = db.load_pose(path, female50)
    np.testing.assert_allclose(record.pose.angles, pose, atol=1e-12)
    doc = json.loads(path.read_text())
    assert doc["body"] == {"name": "male50", "structure": structure_hash(male50)}


def test_a_pose_of_another_structure_is_refused_naming_both(male50, tmp_path):
    mini = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    path = db.save_pose(tmp_path / "mini_pose.json", mini, mini.rest_pose())
    with pytest.raises(PoseFileError) as e:
        db.load_pose(path, male50)
    message = str(e.value)
    assert str(path) in message and "'mini'" in message and "'male50'" in message
    assert structure_hash(mini) in message and structure_hash(male50) in message
    assert "--body" in message  # the fix
    # Re-rooting changes what the rows mean: refused too.
    rerooted = male50.with_root("left_ankle")
    assert structure_hash(rerooted) != structure_hash(male50)


@pytest.mark.parametrize(
    "change, fragment",
    [
        (lambda d: d.update(format="diffbody.body/1"), "not a pose file"),
        (lambda d: d.pop("angles_deg"), "field 'angles_deg' is missing"),
        (lambda d: d.update(kind="movie"), "field 'kind' is 'movie'"),
        (lambda d: d.update(position=[[0, 0, 1]] * 2), "expected angles"),
        (lambda d: d["angles_deg"].update(pelvis=["a", 0, 0]), "not an array of numbers"),
    ],
)
def test_bad_pose_files_name_the_file_and_field(male50, tmp_path, change, fragment):
    path = db.save_pose(tmp_path / "p.json", male50, male50.rest_pose())
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(PoseFileError, match=fragment) as e:
        db.load_pose(path, male50)
    assert str(path) in str(e.value)


def test_save_refuses_mismatched_shapes(male50, tmp_path):
    with pytest.raises(ValueError, match=r"expected \(37, 3\)"):
        db.save_pose(tmp_path / "p.json", male50, db.Pose(jnp.zeros(3), jnp.zeros((5, 3))))
    with pytest.raises(ValueError, match="must end in .json or .npz"):
        db.save_pose(tmp_path / "p.txt", male50, male50.rest_pose())
    with pytest.raises(ValueError, match="kind 'pose'"):
        db.save_pose(tmp_path / "p.json", male50, _poses(male50, 2), kind="pose")


def test_render_draws_a_pose_file(male50, tmp_path, capsys):
    """`diffbody render --pose` draws a chosen frame with the file's overlays; a frame past
    the end and a file of another body are clear errors."""
    poses = _poses(male50, 3)
    targets = {"names": ["left_hand.palm"], "points": np.tile([[0.3, 0.2, 1.0]], (3, 1, 1))}
    path = db.save_pose(tmp_path / "b.npz", male50, poses, overlays={"targets": targets})
    png = tmp_path / "frame.png"
    assert main(["render", "--pose", str(path), "--frame", "2", "--out", str(png)]) == 0
    assert "wrote" in capsys.readouterr().out and png.stat().st_size > 10_000
    err = fails(["render", "--pose", str(path), "--frame", "3", "--out", str(png)], capsys)
    assert "--frame 3" in err and "3 frame(s)" in err
    mini = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    other = db.save_pose(tmp_path / "mini_pose.json", mini, mini.rest_pose())
    err = fails(["render", "--pose", str(other), "--out", str(png)], capsys)
    assert str(other) in err and "'mini'" in err


def test_a_float32_body_saves_and_loads_with_its_pose(male50, tmp_path):
    """A motion-capture body held in float32 (a fit's answer: `motion_limits` widens the
    upper arm to 180 degrees) saves +-180 as +-180, not float32 pi's 180.000005 that the
    schema refuses, and its pose file loads onto it (regression)."""
    wide = db.motion_limits(male50)
    body32 = jax.tree.map(
        lambda a: (
            a.astype(jnp.float32) if isinstance(a, jax.Array) and a.dtype == jnp.float64 else a
        ),
        wide,
    )
    assert np.degrees(float(np.max(body32.swing_hi))) > 180.0  # float32 pi
    path = db.save_body(body32, tmp_path / "fitted.json")
    loaded = db.load_body(path)
    np.testing.assert_allclose(loaded.swing_hi, wide.swing_hi, atol=1e-6)
    pose = db.save_pose(tmp_path / "fitted.pose.json", loaded, loaded.rest_pose())
    assert db.load_pose(pose, loaded).body_name == loaded.name


def test_the_batch_commands_postures_load_and_render(tmp_path, capsys):
    """`diffbody batch` writes its postures beside the CSV: one row each, the status and
    residuals of the CSV, the targets as overlays; a row renders."""
    targets, results = tmp_path / "targets.csv", tmp_path / "results.csv"
    targets.write_text("x,y,z\n0.3,0.2,1.0\n0.15,0.3,0.85\n")
    assert main(arm_batch(targets, results) + ARM_BATCH) == 0
    record = db.load_pose(tmp_path / "results.poses.npz", db.load_body())
    assert record.kind == "batch" and record.n_frames == 2 and record.status == ("success",) * 2
    assert np.all(record.residuals["targets"] < 1e-3)
    np.testing.assert_allclose(record.overlays["targets"]["points"][1], [[0.15, 0.3, 0.85]])
    png = tmp_path / "row1.png"
    assert main(["render", "--pose", str(record.path), "--frame", "1", "--out", str(png)]) == 0
    assert png.stat().st_size > 10_000
