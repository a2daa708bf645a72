"""`diffbody view FILE`: served until Ctrl-C, errors before any serving."""

import sys

import pytest
from command_line import fails

import diffbody as db
import diffbody.cli._view as cli_view
from diffbody.cli import main


def test_missing_file_is_named(tmp_path, capsys):
    err = fails(["view", str(tmp_path / "reach.pose.json")], capsys)
    assert "reach.pose.json: no such pose file" in err


def test_without_viser_the_command_says_what_to_install(male50, tmp_path, capsys, monkeypatch):
    path = db.save_pose(tmp_path / "rest.pose.json", male50, male50.rest_pose())
    monkeypatch.setitem(sys.modules, "viser", None)
    assert "pip install 'diffbody[view]'" in fails(["view", str(path)], capsys)


def test_serves_until_interrupted(male50, arm_raise, tmp_path, capsys, monkeypatch):
    pytest.importorskip("viser", reason="the viewer needs viser: pip install 'diffbody[view]'")
    poses, times = arm_raise
    path = db.save_pose(tmp_path / "raise.pose.json", male50, poses, times=times)
    served = []

    def interrupt(seconds):  # Ctrl-C while the command waits
        served.append(seconds)
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_view, "sleep", interrupt)
    assert main(["view", str(path), "--port", "0"]) == 0
    out = capsys.readouterr().out
    assert served and "5 frames (sequence): open http://127.0.0.1:" in out
