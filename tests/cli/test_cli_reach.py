"""The reach and batch commands (diffbody.cli._main.main called directly)."""

import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from command_line import ARM_BATCH, arm_batch

import diffbody as db
from diffbody.cli._main import main
from diffbody.files import load_pose


def test_reach_command(male50, tmp_path, capsys):
    out, png = tmp_path / "result.json", tmp_path / "pose.png"
    argv = ["reach", "--effector", "left_hand.palm", "--target", "0.3", "0.2", "1.0"]
    assert main(argv + ["--out", str(out), "--png", str(png)]) == 0
    text = capsys.readouterr().out
    assert "reached, residual" in text and "mm" in text and "status" not in text
    assert "left_upper_arm" in text  # a main joint angle, in degrees
    data = json.loads(out.read_text())
    assert data["format"] == "diffbody.pose/1" and data["extra"]["reached"] == [True]
    assert len(data["angles_deg"]["left_forearm"]) == 3 and len(data["position"]) == 3
    record = load_pose(out, male50)
    assert record.kind == "pose" and record.status == "success"
    assert record.residuals["targets"][0] < 1e-3
    assert record.pose.spine_target is None  # the arm reaches it: the spine stays as it was
    palm = db.forward(male50, record.pose).feature_points[male50.feature_index("left_hand.palm")]
    np.testing.assert_allclose(palm, record.overlays["targets"]["points"][0], atol=1e-3)
    assert png.stat().st_size > 0


def test_batch_command(tmp_path, capsys):
    targets, results = tmp_path / "targets.csv", tmp_path / "results.csv"
    targets.write_text("x,y,z\n0.3,0.2,1.0\nnan,0.2,1.0\n0.15,0.3,0.85\n")
    assert main(arm_batch(targets, results) + ARM_BATCH) == 0
    err = capsys.readouterr().err  # the progress bar
    assert "reach: 100%" in err and "3/3 [" in err
    with results.open(newline="") as f:  # the `#` lines record what produced the file
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    assert [r["left_hand.palm.reached"] for r in rows] == ["1", "0", "1"]
    assert [r["left_hand.palm.valid"] for r in rows] == ["1", "0", "1"]
    assert all(np.isfinite(float(r["left_hand.palm.residual"])) for r in rows)
    assert float(rows[0]["left_hand.palm.residual"]) < 1e-3 and "status" in rows[0]


@pytest.mark.parametrize(
    "content, effectors, message",
    [
        ("0.3,0.2,1.0\n0.3,abc,1.0\n", ["left_hand.palm"], "row 2, column 2: not a number"),
        ("0.3,0.2,1.0\n0.3,0.2\n", ["left_hand.palm"], "row 2, column 3: expected 3 columns"),
        ("0.3,0.2,1.0,0.1,0.1\n", ["left_hand.palm", "left_wrist"], "row 1, column 6"),
        ("0.3,0.2,1.0\n", ["left_hand.nope"], "left_hand.nope"),
        ("0.3,0.2,1.0\n", ["left_elbowz"], "unknown effector"),
    ],
)
def test_batch_bad_input_exits_2(tmp_path, capsys, content, effectors, message):
    targets = tmp_path / "bad.csv"
    targets.write_text(content)
    argv = ["batch", str(targets), "--out", str(tmp_path / "r.csv")]
    for e in effectors:
        argv += ["--effector", e]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(targets) in err or "unknown" in err
    assert message in err


CACHE_DIR = "import jax; from diffbody._programs import keep_compiled; keep_compiled(); "
CACHE_DIR += "print(jax.config.jax_compilation_cache_dir)"


@pytest.mark.parametrize(
    "env, expected",
    [
        ({}, "{xdg}/diffbody/jax"),
        ({"JAX_COMPILATION_CACHE_DIR": "{xdg}/mine"}, "{xdg}/mine"),
        ({"DIFFBODY_NO_CACHE": "1"}, "None"),
    ],
)
def test_the_command_line_keeps_compiled_solvers(tmp_path, env, expected):
    """The command line's persistent compilation cache: where it goes, and how to turn it
    off (a subprocess: the setting is global to a process)."""
    clean = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR",)}
    clean.pop("DIFFBODY_NO_CACHE", None)
    clean["XDG_CACHE_HOME"] = str(tmp_path)
    clean.update({k: v.format(xdg=tmp_path) for k, v in env.items()})
    run = subprocess.run(
        [sys.executable, "-c", CACHE_DIR], env=clean, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == expected.format(xdg=tmp_path)


ARM = ["left_upper_arm", "left_forearm", "left_hand"]


def test_reach_segments_off_the_chain_are_named(male50, monkeypatch, tmp_path, capsys):
    """Segments that cannot move the effector are named in a note and left out; the arm
    alone still reaches, and the legs named with it stay as they were."""
    monkeypatch.setattr("diffbody.cli._reach.body_from_args", lambda args: male50)
    out = tmp_path / "result.json"
    argv = ["reach", "--effector", "left_hand.palm", "--target", "0.3", "0.2", "1.0"]
    argv += ["--segments", *ARM, "right_thigh", "left_shank", "--starts", "1"]
    assert main(argv + ["--out", str(out)]) == 0
    text = capsys.readouterr().out
    note = "note: --segments right_thigh left_shank: not on the chain of --effector left_hand.palm"
    assert note in text
    data = json.loads(out.read_text())
    assert data["status"] == "success" and data["spine_target_deg"] is None
    rest = np.degrees(np.asarray(male50.rest_pose().angles))
    for name in ("right_thigh", "left_shank", "left_clavicle"):
        i = male50.segment_names.index(name)
        np.testing.assert_allclose(data["angles_deg"][name], rest[i], atol=1e-9)


@pytest.mark.parametrize(
    "command, effectors, segments",
    [
        ("reach", ["left_hand.palm"], ["right_thigh", "right_shank"]),
        ("reach", ["left_wrist"], ["left_hand"]),  # the wrist ends the forearm
        ("batch", ["left_hand.palm", "right_ankle"], ["head", "whole_body"]),
    ],
)
def test_no_segment_on_the_chain_is_an_error(
    male50, monkeypatch, tmp_path, capsys, command, effectors, segments
):
    """Naming no segment that moves the effector is a mistake, told before any solve with
    the segments given and the chain to choose from, not a start pose "not reached"."""
    monkeypatch.setattr(f"diffbody.cli._{command}.body_from_args", lambda args: male50)
    if command == "batch":
        targets = tmp_path / "t.csv"
        targets.write_text(",".join(["0.3,0.2,1.0"] * len(effectors)) + "\n")
        argv = ["batch", str(targets), "--out", str(tmp_path / "r.csv")]
    else:
        argv = ["reach", "--target", "0.3", "0.2", "1.0"]
    for e in effectors:
        argv += ["--effector", e]
    assert main(argv + ["--segments", *segments]) == 2
    err = capsys.readouterr().err
    which = " ".join(f"--effector {e}" for e in effectors)
    assert f"diffbody: error: --segments {' '.join(segments)}: none of them moves {which}" in err
    assert "Traceback" not in err and "leave --segments out" in err
    chain = err.split(" are ")[1].split(";")[0].split(", ")
    assert chain[0] == "pelvis" and "whole_body" not in chain
    assert "left_forearm" in chain and not set(segments) & set(chain)
    if command == "batch":
        assert "right_foot" not in chain and {"right_thigh", "right_shank"} <= set(chain)
    else:
        assert "right_thigh" not in chain
