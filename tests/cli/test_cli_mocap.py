"""The mocap command end to end, through the command line's own parser (`diffbody.cli.main`,
the console script's entry point, called directly), on two short slices of the shipped static
trial, and its errors on bad input."""

import numpy as np
import pytest

from diffbody.cli import main
from diffbody.files._data_files import data_file
from diffbody.fitting._trc import read_trc, write_trc


def test_mocap_is_a_command(capsys):
    """`diffbody mocap` is a command of the command line itself: its help, through main."""
    with pytest.raises(SystemExit) as exit:
        main(["mocap", "--help"])
    assert exit.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: diffbody mocap ") and "--markerset" in text
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "mocap" in capsys.readouterr().out


@pytest.fixture(scope="module")
def trials(tmp_path_factory):
    """Two 4-frame slices of the shipped static trial, written as TRC files: one to scale
    on, one to fit. With all 49 markers, 4 frames and no prior, the command compiles what
    tests/fitting/test_mocap.py compiles (the suite's persistent cache shares it)."""
    folder = tmp_path_factory.mktemp("mocap")
    static = read_trc(data_file("mocap/subject01_static.trc"))
    paths = folder / "static.trc", folder / "motion.trc"
    write_trc(paths[0], static.between(1.0, 1.05))
    write_trc(paths[1], static.between(2.0, 2.05))
    return paths


def test_mocap_command(trials, tmp_path, capsys):
    out, png = tmp_path / "fit.npz", tmp_path / "fit.png"
    argv = ["mocap", str(trials[0]), str(trials[1]), "--no-prior"]
    assert main(argv + ["--out", str(out), "--png", str(png)]) == 0
    text = capsys.readouterr().out
    assert "4 frames" in text and "marker RMS: mean" in text and "worst marker:" in text
    mean_cm = float(text.split("marker RMS: mean ")[1].split(" cm")[0])
    assert 0.0 < mean_cm < 3.0  # a real fit, not a failed one
    data = np.load(out)
    n, m = len(data["times"]), len(data["marker_names"])
    assert n == 4 and m == 49
    assert data["angles"].shape == (n, len(data["segment_names"]), 3)
    assert data["model_markers"].shape == data["measured_markers"].shape == (n, m, 3)
    assert data["errors"].shape == (n, m) and data["rms"].shape == data["max"].shape == (n,)
    # The saved errors are the distances between the saved model and measured markers.
    gap = np.linalg.norm(data["model_markers"] - data["measured_markers"], axis=-1)
    np.testing.assert_allclose(data["errors"], gap, atol=1e-6)
    np.testing.assert_allclose(data["rms"], np.sqrt(np.nanmean(gap**2, axis=1)), atol=1e-6)
    assert np.all(np.isfinite(data["angles"])) and np.all(data["axial"] > 0)
    assert (tmp_path / "fit.body.json").is_file() and png.stat().st_size > 0
    assert str(tmp_path / "fit.body.json") in text


def test_mocap_bad_file_exits_2(trials, tmp_path, capsys):
    bad = tmp_path / "bad.trc"
    lines = trials[1].read_text().splitlines()
    cells = lines[6].split("\t")
    cells[4] = "1.2.3"
    lines[6] = "\t".join(cells)
    bad.write_text("\n".join(lines) + "\n")
    argv = ["mocap", str(trials[0]), str(bad), "--out", str(tmp_path / "fit.npz")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("diffbody: error: ") and str(bad) in err and "line 7" in err
    assert not (tmp_path / "fit.npz").exists()


@pytest.mark.parametrize(
    "option, value, message",
    [
        ("--markerset", "no-such-set", "no-such-set"),
        ("--axes", "y-up", "unknown lab axes"),
        ("--out", "fit.json", ".npz"),
        ("--time", "9 10", "no frame"),
    ],
)
def test_mocap_bad_options_exit_2(trials, tmp_path, capsys, option, value, message):
    out = ["--out", str(tmp_path / "fit.npz")] if option != "--out" else []
    argv = ["mocap", str(trials[0]), str(trials[1]), option, *value.split(), *out]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
