"""The mocap command end to end, through the command line's own parser (`diffbody.cli.main`,
the console script's entry point, called directly), on two short slices of the shipped static
trial, and its errors on bad input."""

import numpy as np
import pytest

import diffbody as db
from diffbody._joint_angles import angle_names
from diffbody.cli import main
from diffbody.files._data_files import data_file
from diffbody.files._motion_files import read_mot
from diffbody.files._trc import read_trc, write_trc


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
    tests/mocap/test_mocap.py compiles (the suite's persistent cache shares it)."""
    folder = tmp_path_factory.mktemp("mocap")
    static = read_trc(data_file("mocap/subject01_static.trc"))
    paths = folder / "static.trc", folder / "motion.trc"
    write_trc(paths[0], static.between(1.0, 1.05))
    write_trc(paths[1], static.between(2.0, 2.05))
    return paths


def test_mocap_command(trials, tmp_path, capsys):
    out, png = tmp_path / "fit.npz", tmp_path / "fit.png"
    mot, trc = tmp_path / "coordinates.mot", tmp_path / "model.trc"
    isb = tmp_path / "angles.mot"
    argv = ["mocap", str(trials[0]), str(trials[1]), "--no-prior", "--mot", str(mot)]
    argv += ["--angles", str(isb)]
    curves = tmp_path / "curves.png"
    argv += ["--curves", str(curves)]
    assert main(argv + ["--out", str(out), "--png", str(png), "--trc", str(trc)]) == 0
    text = capsys.readouterr().out
    assert "4 frames" in text and "faulty markers: none" in text and "worst other marker:" in text
    # Registered on the trial's frames as well (all 4 of them: fewer than the default 8).
    assert "registered on 4 frames of 1 motion trial(s) as well (--motion-frames)" in text
    # The grades against OpenSim's best practices, the static fit's and the motion's.
    assert "OpenSim's best practices:" in text and "bony landmarks, RMS" in text
    assert "frames with RMS < 2 cm and every marker < 4 cm" in text
    inlier_cm = float(text.split("marker RMS: ")[1].split(" cm over the inliers")[0])
    all_cm = float(text.split("cm over the inliers, ")[1].split(" cm over all markers")[0])
    assert 0.0 < inlier_cm <= all_cm < 3.0  # a real fit, not a failed one
    times, coordinates = read_mot(mot)
    assert len(times) == 4 and list(coordinates) == list(db.coordinate_names())
    assert all(np.all(np.isfinite(v)) for v in coordinates.values())
    assert "OpenSim's coordinates for gait2354" in text
    times, angles = read_mot(isb)
    assert len(times) == 4 and set(angles) == set(angle_names())
    # One file per convention: no ISB column carries an OpenSim coordinate's name with
    # another sign (the knee's is knee_flexion, OpenSim's knee_angle its negative).
    assert not set(angles) & {"knee_angle_r", "knee_angle_l"}
    np.testing.assert_allclose(coordinates["knee_angle_r"], -angles["knee_flexion_r"], atol=1e-4)
    model = read_trc(trc)
    assert model.n_frames == 4 and model.n_markers == 49
    scaled = db.load_body(tmp_path / "fit.body.json")
    record = db.load_pose(out, scaled)
    measured = np.asarray(record.overlays["markers"]["positions"])
    model_markers = np.asarray(record.extra["model_markers"])
    n, m = record.n_frames, len(record.overlays["markers"]["names"])
    assert n == 4 and m == 49 and record.kind == "sequence" and record.times.shape == (n,)
    assert record.pose.angles.shape == (n, scaled.n_segments, 3)
    assert model_markers.shape == measured.shape == (n, m, 3)
    errors, rms = record.residuals["errors"], record.residuals["rms"]
    assert errors.shape == (n, m) and rms.shape == record.residuals["max"].shape == (n,)
    assert record.residuals["outliers"].shape == (n, m) and not record.residuals["outliers"].any()
    np.testing.assert_allclose(model.positions, model_markers, atol=1e-6)
    # The saved errors are the distances between the saved model and measured markers.
    gap = np.linalg.norm(model_markers - measured, axis=-1)
    np.testing.assert_allclose(errors, gap, atol=1e-6)
    np.testing.assert_allclose(rms, np.sqrt(np.nanmean(gap**2, axis=1)), atol=1e-6)
    assert np.all(np.isfinite(record.pose.angles)) and np.all(np.asarray(record.scale["axial"]) > 0)
    # The fit's pose file renders on its scaled body, a frame with its measured markers.
    frame = tmp_path / "frame.png"
    argv = ["render", "--pose", str(out), "--body", str(tmp_path / "fit.body.json")]
    assert main(argv + ["--frame", "3", "--out", str(frame)]) == 0
    assert frame.stat().st_size > 10_000
    assert (tmp_path / "fit.body.json").is_file() and png.stat().st_size > 0
    assert curves.stat().st_size > 10_000
    assert str(tmp_path / "fit.body.json") in text


def test_mocap_with_opensims_files(trials, tmp_path, capsys, monkeypatch):
    """OpenSim's marker set (.xml) and IK set-up (--tasks: its 31 applied markers, weights
    as in the file) drive the command; the set's markers the tasks switch off weigh 0.
    Registered on the static trial alone (--motion-frames 0): no line says otherwise.
    --no-velocity reaches the motion fit."""
    from diffbody.mocap import _motion_fit

    asked = []

    def fit_motion(*args, **kwargs):
        asked.append(kwargs["velocity"])
        return real(*args, **kwargs)

    real = _motion_fit.fit_motion
    monkeypatch.setattr(_motion_fit, "fit_motion", fit_motion)
    out = tmp_path / "fit.npz"
    argv = ["mocap", str(trials[0]), str(trials[1]), "--no-prior", "--out", str(out)]
    argv += ["--motion-frames", "0", "--no-velocity"]
    argv += ["--markerset", str(data_file("mocap/gait2354_Scale_MarkerSet.xml"))]
    argv += ["--tasks", str(data_file("mocap/subject01_Setup_IK.xml"))]
    assert main(argv) == 0
    text = capsys.readouterr().out
    record = db.load_pose(out)
    assert len(record.overlays["markers"]["names"]) == 39 and "4 frames, 39 markers fitted" in text
    assert np.all(np.isfinite(record.pose.angles)) and record.status == ("converged",) * 4
    assert "registered on" not in text and asked == [False]


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
        ("--mot", "angles.csv", ".mot"),
        ("--tasks", "no-such-setup.xml", "no-such-setup.xml"),
    ],
)
def test_mocap_bad_options_exit_2(trials, tmp_path, capsys, option, value, message):
    out = ["--out", str(tmp_path / "fit.npz")] if option != "--out" else []
    argv = ["mocap", str(trials[0]), str(trials[1]), option, *value.split(), *out]
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_mocap_motion_frames_must_be_a_count(trials, tmp_path, capsys):
    argv = ["mocap", str(trials[0]), str(trials[1]), "--motion-frames", "-1"]
    with pytest.raises(SystemExit) as stop:
        main(argv + ["--out", str(tmp_path / "fit.npz")])
    assert stop.value.code == 2
    assert "--motion-frames: must be an integer >= 0, got '-1'" in capsys.readouterr().err
