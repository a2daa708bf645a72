"""The webb command's anchor (`--anchor FILE`, `--anchor-frame N`): the reflections it gives
reach the pipeline as `lift` takes them and pin continuity to the truth; bad anchor files
and frames are refused before any work, naming the file, the entry and the fix."""

import json

import numpy as np
import pytest
from command_line import fails

from diffbody.cli import main
from diffbody.files._body_file import data_file
from diffbody.images._joint_tree import default_joint_tree
from diffbody.images._lifting import lift
from diffbody.images._motions import reaching_motion
from diffbody.images._pinhole import camera_around, image_sequence
from diffbody.images._webb import true_reflections

F = 1000.0  # px
FRAME = 20  # mid-reach: every part's two candidates well apart (at frame 0 some meet)


@pytest.fixture(scope="module")
def reach(male50, tmp_path_factory):
    """60 frames of the reaching body seen from 3 m, no noise (the example's shape, so the
    compiled pipeline is shared), written as the command's input files, and the true
    reflections. Continuity with no anchor matches the truth in 54 % of (frame, part)."""
    tree = default_joint_tree()
    camera = camera_around([0.0, 0.0, 1.0], 3.0, 30.0, 1.2, F)
    seq = image_sequence(tree, camera, reaching_motion(male50, tree, 60))
    folder = tmp_path_factory.mktemp("webb")
    points, depth = folder / "points.csv", folder / "depth.csv"
    header = ",".join(f"{n}.{c}" for n in tree.names for c in "uv")
    uv = np.asarray(seq.uv)
    np.savetxt(
        points, uv.reshape(len(uv), -1), fmt="%.17g", delimiter=",", header=header, comments=""
    )
    np.savetxt(depth, np.asarray(seq.root_depth), fmt="%.17g")
    truth = np.asarray(true_reflections(tree, seq.joints))
    return tree, seq, points, depth, truth


def _anchor_file(path, tree, codes) -> str:
    path.write_text(json.dumps({n: ("near", "far")[c] for n, c in zip(tree.part_names, codes)}))
    return str(path)


def _argv(points, depth, out) -> list[str]:
    return ["webb", str(points), "--focal", str(F), "--root-depth", str(depth), "--out", str(out)]


def test_anchor_from_the_truth_gives_the_true_reflections(reach, tmp_path, capsys):
    """The truth's reflections in one frame, from a file: that frame takes them exactly,
    continuity carries them to 97 % of the rest (54 % with no anchor), and the result is
    `lift`'s with the same anchor and frame."""
    tree, seq, points, depth, truth = reach
    anchor = _anchor_file(tmp_path / "anchor.json", tree, truth[FRAME])
    out = tmp_path / "lengths.json"
    argv = _argv(points, depth, out) + ["--anchor", anchor, "--anchor-frame", str(FRAME)]
    assert main(argv) == 0
    assert f"the reflections of 14 of 14 parts in frame {FRAME}" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    reflections = np.asarray(doc["reflections"])
    np.testing.assert_array_equal(reflections[FRAME], truth[FRAME])
    assert (reflections == truth).mean() > 0.95
    assert doc["anchor"]["frame"] == FRAME
    knee = tree.part_names.index("left_hip->left_knee")
    assert (
        doc["anchor"]["reflections"]["left_hip->left_knee"] == ("near", "far")[truth[FRAME, knee]]
    )
    choice, lifted = lift(tree, seq.uv, seq.root_depth, F, anchor=truth[FRAME], anchor_frame=FRAME)
    np.testing.assert_array_equal(reflections, np.asarray(choice.reflections))
    lengths = [doc["lengths_m"][n] for n in tree.part_names]
    np.testing.assert_allclose(lengths, np.asarray(lifted.lengths), rtol=1e-9)


def test_anchor_without_refinement_and_from_the_end(reach, tmp_path):
    """--no-refine takes the anchor too; a negative frame counts from the end; parts left
    out of the file are left to continuity, codes 0 and 1 as the output writes them."""
    tree, seq, points, depth, truth = reach
    frame = FRAME - 60
    some = {n: int(c) for n, c in zip(tree.part_names[:8], truth[frame])}
    anchor = tmp_path / "anchor.json"
    anchor.write_text(json.dumps(some))
    out = tmp_path / "lengths.json"
    argv = _argv(points, depth, out) + ["--no-refine", "--anchor", str(anchor)]
    assert main(argv + ["--anchor-frame", str(frame)]) == 0
    doc = json.loads(out.read_text())
    reflections = np.asarray(doc["reflections"])
    np.testing.assert_array_equal(reflections[FRAME, :8], truth[FRAME, :8])
    assert (reflections[:, :8] == truth[:, :8]).mean() > 0.95
    assert doc["anchor"] == {
        "frame": FRAME,
        "reflections": {n: ("near", "far")[c] for n, c in some.items()},
    }
    assert doc["status"] is None


EXAMPLE = ["webb", str(data_file("webb/example_points.csv")), "--focal", "1000"]
EXAMPLE += ["--root-depth", str(data_file("webb/example_depth.csv"))]


def _fails(argv, capsys, monkeypatch) -> str:
    """Run the command line, which must exit 2 before any solve; its stderr."""
    monkeypatch.setattr("diffbody.images._lifting.lift", lambda *a, **k: pytest.fail("lifted"))
    monkeypatch.setattr(
        "diffbody.images._reflections.choose_reflections",
        lambda *a, **k: pytest.fail("chose reflections"),
    )
    err = fails(argv, capsys)
    assert err.startswith("diffbody: error: ") or "usage:" in err
    return err


@pytest.mark.parametrize(
    "content, message",
    [
        ("{", "not JSON (line 1, column 2: "),
        ('{"center_hip->left_hip": "near",}', "not JSON (line 1, column 33: "),
        ('["near", "far"]', "expected a JSON object of part reflections, got an array"),
        ('"near"', "expected a JSON object of part reflections, got a string"),
        ("{}", "no part's reflection given; name at least one part"),
        ('{"left_knee": "far"}', "entry 'left_knee': no such part of the skeleton"),
        ('{"left_hip->left_knee": "up"}', "entry 'left_hip->left_knee': the reflection must"),
        ('{"left_hip->left_knee": 2}', 'must be "near" or "far" (or 0 near, 1 far), got 2'),
        ('{"left_hip->left_knee": -1}', "got -1; leave a part out when unknown"),
        ('{"left_hip->left_knee": true}', "got true"),
        ('{"left_hip->left_knee": 1.0}', "got 1.0"),
        ('{"left_hip->left_knee": "far", "left_hip->left_knee": "near"}', "given twice"),
    ],
    ids=[
        "truncated",
        "trailing-comma",
        "array",
        "string",
        "empty",
        "unknown-part",
        "bad-word",
        "bad-code",
        "free-code",
        "boolean",
        "float",
        "twice",
    ],
)
def test_bad_anchor_file(tmp_path, capsys, monkeypatch, content, message):
    anchor = tmp_path / "anchor.json"
    anchor.write_text(content)
    err = _fails(EXAMPLE + ["--anchor", str(anchor)], capsys, monkeypatch)
    assert f"diffbody: error: {anchor}: " in err and message in err
    if "no such part" in message:
        assert "left_hip->left_knee" in err  # the parts to choose from
    if "JSON object" in message or "no part" in message:
        assert '{"center_hip->left_hip": "near"' in err  # what a good file looks like


@pytest.mark.parametrize("kind", ["missing", "folder", "not-utf8"])
def test_unreadable_anchor_file(tmp_path, capsys, monkeypatch, kind):
    anchor = tmp_path / "anchor.json"
    if kind == "folder":
        anchor.mkdir()
    elif kind == "not-utf8":
        anchor.write_bytes(b'{"left_hip->left_knee": "\xff"}')
    err = _fails(EXAMPLE + ["--anchor", str(anchor)], capsys, monkeypatch)
    assert str(anchor) in err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--anchor-frame", "60"], "--anchor-frame 60: {points} has 60 frames; give 0 to 59"),
        (["--anchor-frame", "-61"], "--anchor-frame -61: {points} has 60 frames"),
        (["--anchor-frame", "x"], "argument --anchor-frame: invalid int value: 'x'"),
    ],
)
def test_bad_anchor_frame(tmp_path, capsys, monkeypatch, extra, message):
    anchor = tmp_path / "anchor.json"
    anchor.write_text('{"left_hip->left_knee": "far"}')
    err = _fails(EXAMPLE + ["--anchor", str(anchor)] + extra, capsys, monkeypatch)
    assert message.format(points=data_file("webb/example_points.csv")) in err


def test_anchor_frame_needs_an_anchor(capsys, monkeypatch):
    err = _fails(EXAMPLE + ["--anchor-frame", "3"], capsys, monkeypatch)
    assert "--anchor-frame 3: needs --anchor FILE" in err
