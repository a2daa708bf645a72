"""The command line on bad input: exit status 2 and a message naming the file or option,
never a traceback. Every case fails before any solve, so these run in milliseconds; the last
test solves the rows a gap in the data leaves valid."""

import csv

import numpy as np
import pytest
from command_line import ARM_BATCH, arm_batch, fails

from diffbody.cli._main import main
from diffbody.files._targets_file import read_targets

REACH = ["reach", "--effector", "left_hand.palm", "--target", "0.3", "0.2", "1.0"]


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", "no target rows, the file is empty; each row is x,y,z"),
        (b"x,y,z\n", "a header but no target rows; each row is x,y,z"),
        (b"\n\n  \n", "no target rows, only blank lines"),
        (b"x;y;z\n0.3;0.2;1.0\n", "row 1: columns are separated by commas, not semicolons"),
        (b"0,3;0,2;1,0\n", "row 1: columns are separated by commas, not semicolons"),
        (b"0.3\t0.2\t1.0\n", "row 1: columns are separated by commas, not tabs"),
        (b"0.3 0.2 1.0\n", "row 1: columns are separated by commas, not spaces"),
        (b"0.3,0.2,1.0\n\xff\xfe0.3,0.2\n", "row 2: not UTF-8 text"),
        (b"0.3,0.2,1.0\n0.3,0.2\n", "row 2, column 3: expected 3 columns"),
        (b"0.3,0.2,1.0,\n", "row 1, column 4: expected 3 columns"),
        (b"0.3,,1.0\n", "row 1, column 2: empty cell"),
        (b"x,y,z\n0.3,abc,1.0\n", "row 2, column 2: not a number: 'abc'"),
        (b"x,y,z\nx,y,z\n", "row 2, column 1: not a number: 'x'"),
    ],
    ids=[
        "empty",
        "header-only",
        "blank-lines",
        "semicolons",
        "semicolons-decimal-commas",
        "tabs",
        "spaces",
        "not-utf8",
        "short-row",
        "trailing-comma",
        "empty-cell",
        "text-cell",
        "two-headers",
    ],
)
def test_bad_targets_csv(tmp_path, capsys, content, message):
    targets = tmp_path / "targets.csv"
    targets.write_bytes(content)
    argv = ["batch", str(targets), "--effector", "left_hand.palm"]
    err = fails(argv + ["--out", str(tmp_path / "r.csv")], capsys)
    assert f"diffbody: error: {targets}: {message}" in err


def test_targets_csv_is_a_folder(tmp_path, capsys):
    err = fails(["batch", str(tmp_path), "--effector", "left_hand.palm"], capsys)
    assert f"{tmp_path}: is a directory" in err


def test_targets_csv_missing(tmp_path, capsys):
    missing = tmp_path / "nope.csv"
    err = fails(["batch", str(missing), "--effector", "left_hand.palm"], capsys)
    assert str(missing) in err


def test_results_would_overwrite_the_targets(tmp_path, capsys):
    targets = tmp_path / "t.csv"
    targets.write_text("0.3,0.2,1.0\n")
    argv = ["batch", str(targets), "--effector", "left_hand.palm", "--out", str(targets)]
    assert "is the targets file" in fails(argv, capsys)
    assert targets.read_text() == "0.3,0.2,1.0\n"


def test_a_good_targets_csv_parses(tmp_path):
    """Header, blank lines, spaces around cells and a spreadsheet's byte-order mark."""
    targets = tmp_path / "t.csv"
    targets.write_bytes(
        "\ufeff\nleft.x, left.y, left.z,right.x,right.y,right.z\r\n\r\n"
        "0.3, 0.2, 1.0, 0.3,-0.2,1.0\r\n-1e-1,0,2,0.1,0.1,0.1\r\n".encode()
    )
    xyz = read_targets(str(targets), 2)
    assert xyz.shape == (2, 2, 3)
    np.testing.assert_array_equal(xyz[1], [[-0.1, 0.0, 2.0], [0.1, 0.1, 0.1]])
    plain = tmp_path / "plain.csv"
    plain.write_text("0.3,0.2,1.0\n0.15,0.3,0.85")  # no header, no final newline
    expected = [[0.3, 0.2, 1.0], [0.15, 0.3, 0.85]]
    np.testing.assert_array_equal(read_targets(str(plain), 1)[:, 0], expected)


@pytest.mark.parametrize(
    "extra, option",
    [
        (["--starts", "0"], "--starts"),
        (["--starts", "-1"], "--starts"),
        (["--starts", "x"], "--starts"),
        (["--starts", "1.5"], "--starts"),
    ],
)
def test_reach_bad_starts(capsys, extra, option):
    err = fails(REACH + extra, capsys)
    assert f"argument {option}: must be a positive integer" in err


@pytest.mark.parametrize("extra", [["--chunk-size", "0"], ["--starts", "0"]])
def test_batch_bad_positive_ints(tmp_path, capsys, extra):
    targets = tmp_path / "t.csv"
    targets.write_text("0.3,0.2,1.0\n")
    err = fails(["batch", str(targets), "--effector", "left_hand.palm"] + extra, capsys)
    assert f"argument {extra[0]}: must be a positive integer" in err


@pytest.mark.parametrize("value", ["nan", "inf", "Infinity", "1e999", "abc"])
def test_reach_bad_target(capsys, value):
    argv = ["reach", "--effector", "left_hand.palm", "--target", "0.3", value, "1.0"]
    err = fails(argv, capsys)
    assert "argument --target: must be a finite number" in err and repr(value) in err


@pytest.mark.parametrize("value", ["bogus", "30", "30,x", "30,15,2", "nan,0"])
def test_render_bad_view(tmp_path, capsys, value):
    err = fails(["render", "--out", str(tmp_path / "b.png"), "--view", value], capsys)
    assert "argument --view: unknown view" in err
    assert all(name in err for name in ("front", "back", "perspective", "AZ,EL"))


def _command(kind: str, tmp_path) -> list[str]:
    if kind == "batch":
        targets = tmp_path / "t.csv"
        targets.write_text("0.3,0.2,1.0\n")
        return ["batch", str(targets), "--effector", "left_hand.palm"]
    return REACH if kind == "reach" else ["render"]


@pytest.mark.parametrize(
    "kind, option",
    [("reach", "--out"), ("reach", "--png"), ("batch", "--out"), ("render", "--out")],
)
def test_output_into_a_missing_folder(tmp_path, capsys, monkeypatch, kind, option):
    # The check comes before the body is loaded: a loader that ran would fail the test.
    monkeypatch.setattr(
        f"diffbody.cli._{kind}.body_from_args", lambda args: pytest.fail("loaded the body")
    )
    out = tmp_path / "missing" / "out.file"
    err = fails(_command(kind, tmp_path) + [option, str(out)], capsys)
    assert f"{option} {out}: folder {out.parent} does not exist" in err
    assert not out.parent.exists()


@pytest.mark.parametrize(
    "kind, option",
    [("reach", "--out"), ("reach", "--png"), ("batch", "--out"), ("render", "--out")],
)
def test_output_is_a_folder(tmp_path, capsys, monkeypatch, kind, option):
    monkeypatch.setattr(
        f"diffbody.cli._{kind}.body_from_args", lambda args: pytest.fail("loaded the body")
    )
    err = fails(_command(kind, tmp_path) + [option, str(tmp_path)], capsys)
    assert f"{option} {tmp_path}: is a folder" in err


def test_output_under_a_file(tmp_path, capsys):
    (tmp_path / "f").write_text("")
    out = tmp_path / "f" / "x.json"
    err = fails(REACH + ["--out", str(out)], capsys)
    assert f"--out {out}: {tmp_path / 'f'} is not a folder" in err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--segments", "left_upper_arm", "left_elbow_thing"], "--segments: unknown segment"),
        (["--effector", "left_hand.nope"], "--effector: unknown feature 'left_hand.nope'"),
        (["--effector", "left_elbowz"], "--effector: unknown effector 'left_elbowz'"),
    ],
)
def test_unknown_names(male50, monkeypatch, capsys, extra, message):
    monkeypatch.setattr("diffbody.cli._reach.body_from_args", lambda args: male50)  # loaded once
    argv = REACH + extra  # a second --effector replaces the first
    err = fails(argv, capsys)
    assert message in err and "diffbody info --names" in err


def test_unknown_variant(capsys):
    err = fails(["info", "--variant", "child5"], capsys)
    assert "'child5'" in err and "male50" in err


@pytest.mark.parametrize("kind", ["folder", "not-utf8", "missing"])
def test_bad_body_file(tmp_path, capsys, kind):
    body = tmp_path / "body.json"
    if kind == "folder":
        body.mkdir()
    elif kind == "not-utf8":
        body.write_bytes(b'{"name": "\xff"}')
    err = fails(["info", "--body", str(body)], capsys)
    assert str(body) in err


def test_a_missing_value_passes_through_as_an_invalid_row(tmp_path, capsys):
    """nan or inf in a row is a gap in the data, not a malformed file: the row is solved as
    an invalid target (status invalid_target, valid 0), as `solve_reach_batch` does, and
    the rows around it are solved as usual."""
    targets, results = tmp_path / "gaps.csv", tmp_path / "results.csv"
    targets.write_text("0.3,nan,1.0\n0.3,0.2,1.0\n0.3,0.2,-inf\n0.3,0.2,1e999\n")
    xyz = read_targets(str(targets), 1)
    finite = np.isfinite(xyz).all(axis=(1, 2))
    assert xyz.shape == (4, 1, 3) and finite.tolist() == [False, True, False, False]
    assert main(arm_batch(targets, results) + ARM_BATCH) == 0
    assert "1 of 4 rows reached" in capsys.readouterr().out
    with results.open(newline="") as f:  # the `#` lines: what produced the file
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    assert [r["row"] for r in rows] == ["0", "1", "2", "3"]
    assert [r["status"] for r in rows] == ["invalid_target", "success"] + ["invalid_target"] * 2
    assert [r["left_hand.palm.valid"] for r in rows] == ["0", "1", "0", "0"]
    assert [r["left_hand.palm.reached"] for r in rows] == ["0", "1", "0", "0"]
