"""Pictures and the command line (the README's main job)."""

import subprocess
import sys

import numpy as np
import pytest

import diffbody as db
from diffbody.cli._main import main


def _image(path):
    import matplotlib.image as mpimg

    return mpimg.imread(path)


def test_render_draws_the_body(male50, tmp_path):
    path = db.render(male50, male50.rest_pose(), tmp_path / "front.png", view="front")
    img = _image(path)
    assert img.shape[0] > 300 and img.shape[1] > 200
    # Shaded spheres: many distinct colours, and the body covers a good part of the picture.
    rgb = img[..., :3].reshape(-1, 3)
    body_pixels = np.mean(np.any(np.abs(rgb - 1.0) > 0.05, axis=1))
    assert 0.1 < body_pixels < 0.9
    assert len(np.unique(np.round(rgb, 2), axis=0)) > 50


def test_render_several_views_and_angles(male50, tmp_path):
    path = db.render(
        male50,
        male50.rest_pose(),
        tmp_path / "views.png",
        view=["front", "left", (30.0, 20.0)],
        features=True,
        skeleton=True,
    )
    one = _image(db.render(male50, male50.rest_pose(), tmp_path / "one.png"))
    assert _image(path).shape[1] > 2 * one.shape[1]


def test_render_rejects_unknown_view(male50, tmp_path):
    with pytest.raises(ValueError, match="front"):
        db.render(male50, male50.rest_pose(), tmp_path / "x.png", view="sideways")


def test_cli_render_and_info(tmp_path, capsys):
    out = tmp_path / "body.png"
    assert main(["render", "--out", str(out), "--view", "front"]) == 0
    assert out.is_file()
    printed = capsys.readouterr().out
    assert "stature 1.75" in printed and "wrote" in printed
    assert main(["info", "--variant", "female50", "--names"]) == 0
    assert "left_hand.palm" in capsys.readouterr().out


def test_cli_reports_bad_input_clearly(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert main(["info", "--body", str(bad)]) == 2
    assert "bad.json" in capsys.readouterr().err


def test_python_dash_m_entry_point():
    out = subprocess.run(
        [sys.executable, "-m", "diffbody", "info"], capture_output=True, text=True, check=True
    )
    assert "male50" in out.stdout
