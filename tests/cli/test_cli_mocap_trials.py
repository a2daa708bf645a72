"""`diffbody mocap STATIC TRIALS_DIR/`: a folder (or a glob pattern) of trials fitted against
one static registration, each trial's files written as it finishes, a summary CSV
(`trials.csv`) appended a trial at a time, clean interrupts and `--resume`.

The trials are 4-frame slices of the shipped static trial, as tests/cli/test_cli_mocap.py's,
so that one compiled fit serves them all. The signals need a process of their own
(`python -m diffbody mocap`, float64 and the suite's compilation cache, as
tests/cli/test_cli_batch_stream.py runs `batch`); the rest run in this process.
"""

import csv
import hashlib
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from command_line import data_lines, without_timestamp

import diffbody as db
from diffbody.cli import main
from diffbody.files import structure_hash
from diffbody.files._data_files import data_file
from diffbody.files._trc import read_trc, write_trc

COLUMNS = "trial,sha256,frames,markers,status,converged,marker_rms_m,notes\n"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A static trial and a folder of two trials (a.trc, b.trc), 4 frames each."""
    folder = tmp_path_factory.mktemp("trials")
    static = read_trc(data_file("mocap/subject01_static.trc"))
    (folder / "trials").mkdir()
    write_trc(folder / "static.trc", static.between(1.0, 1.05))
    write_trc(folder / "trials" / "a.trc", static.between(2.0, 2.05))
    write_trc(folder / "trials" / "b.trc", static.between(3.0, 3.05))
    return folder / "static.trc", folder / "trials"


def argv(static, trials, out, *extra):
    # Registered on 4 frames spread over both trials: the programs of one 4-frame trial
    # (tests/cli/test_cli_mocap.py).
    command = ["mocap", str(static), str(trials), "--no-prior", "--mot", "--motion-frames", "4"]
    return command + ["--out", str(out), *extra]


@pytest.fixture(scope="module")
def uninterrupted(recorded, tmp_path_factory):
    """The output folder of a run that was never stopped, and what it printed."""
    static, trials = recorded
    out = tmp_path_factory.mktemp("uninterrupted") / "fits"
    assert main(argv(static, trials, out)) == 0
    return out


def snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def assert_same_fits(out, reference, names=("a", "b")):
    """The resumed folder's fits are the uninterrupted run's."""
    assert without_timestamp(out / "trials.csv") == without_timestamp(reference / "trials.csv")
    for name in names:
        got, want = db.load_pose(out / f"{name}.npz"), db.load_pose(reference / f"{name}.npz")
        np.testing.assert_array_equal(got.pose.angles, want.pose.angles)
        assert got.status == want.status
        assert (out / f"{name}.mot").read_bytes() == (reference / f"{name}.mot").read_bytes()
    assert (out / "body.json").read_bytes() == (reference / "body.json").read_bytes()
    assert not [p.name for p in out.iterdir() if ".partial" in p.name]


def test_a_folder_of_trials(recorded, uninterrupted, capsys):
    """(a) Both trials' files and a two-row summary whose header records the run."""
    static, trials = recorded
    out = uninterrupted
    names = {p.name for p in out.iterdir()}
    assert names == {"a.npz", "a.mot", "b.npz", "b.mot", "body.json", "body.spine.json"} | {
        "trials.csv"
    }
    lines = (out / "trials.csv").read_text().splitlines(True)
    header = dict(line[2:].rstrip("\n").split(": ", 1) for line in lines if line[0] == "#")
    assert header["format"] == "diffbody.mocap-trials/1"
    assert header["static"] == str(static)
    assert header["static-sha256"] == hashlib.sha256(static.read_bytes()).hexdigest()
    assert header["body"] == "male50" and header["body-structure"] == structure_hash(db.load_body())
    assert len(header["body-dimensions"]) == 16 and header["markerset"] == "opensim-gait"
    assert header["prior"] == "off" and header["keep-zeros"] == "off" and header["time"] == "(all)"
    assert header["tasks"] == "(none)" and header["float"] == "float64"
    assert header["measured"] == "(none)" and header["motion-frames"] == "4"
    assert header["velocity"] == "on"
    assert data_lines(out / "trials.csv")[0] == COLUMNS
    rows = list(csv.DictReader(data_lines(out / "trials.csv")))
    assert [r["trial"] for r in rows] == ["a.trc", "b.trc"]
    for r in rows:
        assert r["sha256"] == hashlib.sha256((trials / r["trial"]).read_bytes()).hexdigest()
        assert (r["frames"], r["markers"], r["status"], r["converged"]) == (
            "4",
            "49",
            "converged",
            "4",
        )
        assert 0 < float(r["marker_rms_m"]) < 0.03 and r["notes"] == ""
    scaled = db.load_body(out / "body.json")
    record = db.load_pose(out / "b.npz", scaled)
    assert record.n_frames == 4 and record.kind == "sequence"
    rms = float(rows[1]["marker_rms_m"])
    np.testing.assert_allclose(np.sqrt(np.nanmean(record.residuals["errors"] ** 2)), rms, 1e-6)
    times, coordinates = db.read_mot(out / "a.mot")
    assert len(times) == 4 and list(coordinates) == list(db.coordinate_names())
    assert all(np.all(np.isfinite(v)) for v in coordinates.values())


def start(static, trials, out, *extra):
    """`diffbody mocap` in a process of its own, float64 as the tests run."""
    env = dict(os.environ, JAX_ENABLE_X64="1")
    command = [sys.executable, "-m", "diffbody"] + argv(static, trials, out, *extra)
    return subprocess.Popen(
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def stop_after_first(process, out, signum):
    """Send `signum` once the summary holds its first trial, while the process still runs
    (else the test proves nothing); its exit status and stderr."""
    summary = out / "trials.csv"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:
        if summary.exists() and len(data_lines(summary)) >= 2:
            break
        time.sleep(0.01)
    assert process.poll() is None, process.communicate()
    process.send_signal(signum)
    _, err = process.communicate(timeout=120)
    return process.returncode, err


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupted_run_keeps_its_trials_and_resumes(
    recorded, uninterrupted, tmp_path, capsys, signum, code
):
    """(b) A signal after the first trial: a clean stop that keeps it; --resume fits the
    other and gives the uninterrupted run's summary and fits."""
    static, trials = recorded
    out = tmp_path / "fits"
    status, err = stop_after_first(start(static, trials, out), out, signum)
    assert status == code, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    message = f"interrupted after 1 of 2 trials; {out} holds them; rerun with --resume"
    assert message in err
    assert len(data_lines(out / "trials.csv")) == 2 and (out / "a.npz").exists()
    assert not (out / "b.npz").exists()

    assert main(argv(static, trials, out, "--resume")) == 0
    text = capsys.readouterr().out
    assert f"resuming {out} after 1 of 2 trials" in text and "a.trc:" not in text
    assert "b.trc: 4 frames" in text
    assert_same_fits(out, uninterrupted)


@pytest.mark.slow
def test_a_killed_run_leaves_whole_files_and_resumes(recorded, uninterrupted, tmp_path, capsys):
    """(c) SIGKILL gives the run no say: what it leaves is whole files and whole rows, or
    temporaries named `.partial`; --resume removes those (and a partial last line, as a
    crash in the middle of a write could leave) and completes the run."""
    static, trials = recorded
    out = tmp_path / "fits"
    status, _ = stop_after_first(start(static, trials, out), out, signal.SIGKILL)
    assert status == -signal.SIGKILL
    rows = list(csv.DictReader(data_lines(out / "trials.csv")))
    assert rows and rows[0]["trial"] == "a.trc" and rows[0]["status"] == "converged"
    assert (out / "trials.csv").read_text().endswith("\n")
    for p in out.iterdir():
        if ".partial" not in p.name and p.suffix == ".npz":
            assert db.load_pose(p).n_frames == 4  # whole
    # What a kill in the middle of b's writes would leave.
    (out / "b.npz.partial").mkdir(exist_ok=True)
    (out / "b.npz.partial" / "b.npz").write_bytes(b"PK")
    (out / "b.mot.partial").write_bytes(b"half")
    with (out / "trials.csv").open("a") as f:
        f.write("b.trc,22c5")
    assert main(argv(static, trials, out, "--resume")) == 0
    assert f"resuming {out} after 1 of 2 trials" in capsys.readouterr().out
    assert_same_fits(out, uninterrupted)


@pytest.mark.parametrize(
    "change, message",
    [
        ("static", "the static trial changed (sha256 "),
        ("trial", "the trial b.trc changed (sha256 "),
        (["--variant", "female50"], "the body changed (male50: structure"),
        ("prior", "the prior (--no-prior) changed from off to on"),
        (["--keep-zeros"], "--keep-zeros changed from off to on"),
        (["--time", "2", "4"], "--time changed from (all) to 2.0 4.0"),
        (["--opensim-model", "model.osim"], "--opensim-model changed from gait2354 to model.osim"),
        (
            ["--measure", "stature=1.8"],
            "the readings (--measure, --measure-sd) changed from (none) to stature=1.8 sd=0.005",
        ),
        (
            ["--motion-frames", "0"],
            "the registration's frames of the trials (--motion-frames) changed from 4 to 0",
        ),
        (
            ["--no-velocity"],
            "the motion fits' velocity term (--no-velocity) changed from on to off",
        ),
    ],
)
def test_resume_refuses_a_different_run(recorded, uninterrupted, tmp_path, capsys, change, message):
    """(d) --resume of a folder begun with another static trial, body, setting or trial is
    refused before any solve, naming what changed, and the folder is left as it was."""
    static, trials = recorded
    out = tmp_path / "fits"
    out.mkdir()
    for name, data in snapshot(uninterrupted).items():
        (out / name).write_bytes(data)
    before = snapshot(out)
    command = argv(static, trials, out, "--resume")
    if change == "static":
        other = tmp_path / "static.trc"
        write_trc(other, read_trc(static).between(1.0, 1.034))
        command = argv(other, trials, out, "--resume")
    elif change == "trial":
        changed = tmp_path / "trials"
        changed.mkdir()
        (changed / "a.trc").write_bytes((trials / "a.trc").read_bytes())
        write_trc(changed / "b.trc", read_trc(trials / "b.trc").between(3.0, 3.034))
        command = argv(static, changed, out, "--resume")
    elif change == "prior":
        command.remove("--no-prior")
    else:
        command += change
    assert main(command) == 2
    err = capsys.readouterr().err
    assert f"diffbody: error: --resume {out}: {message}" in err, err
    assert "rerun as it was begun, or without --resume to start over" in err
    assert err.count("changed") == 1  # only what changed is named
    assert snapshot(out) == before


def test_a_bad_trial_is_told_and_skipped(recorded, uninterrupted, tmp_path, capsys):
    """(e) A trial that cannot be read is a row with status `error` and the reason; the
    other is fitted, and the registration fits its frames alone; the exit status is 1.
    Without --resume a folder's summary is begun anew."""
    static, trials = recorded
    folder = tmp_path / "trials"
    folder.mkdir()
    (folder / "a.trc").write_bytes((trials / "a.trc").read_bytes())
    lines = (trials / "b.trc").read_text().splitlines()
    cells = lines[6].split("\t")
    cells[4] = "1.2.3"
    lines[6] = "\t".join(cells)
    (folder / "bad.trc").write_text("\n".join(lines) + "\n")
    (folder / "notes.txt").write_text("not a trial")
    out = tmp_path / "fits"
    out.mkdir()
    (out / "trials.csv").write_text((uninterrupted / "trials.csv").read_text())
    assert main(argv(static, folder, out)) == 1
    text = capsys.readouterr().out
    assert f"{folder / 'bad.trc'}: skipped: " in text and "line 7" in text
    assert "registered on 4 frames of 1 motion trial(s) as well" in text
    rows = list(csv.DictReader(data_lines(out / "trials.csv")))
    assert [(r["trial"], r["status"]) for r in rows] == [
        ("a.trc", "converged"),
        ("bad.trc", "error"),
    ]
    assert "line 7" in rows[1]["notes"] and rows[1]["frames"] == ""
    assert rows[1]["sha256"] == hashlib.sha256((folder / "bad.trc").read_bytes()).hexdigest()
    assert (out / "a.npz").exists() and not (out / "bad.npz").exists()
    # --resume keeps the error (the file is as it was): nothing is fitted again.
    assert main(argv(static, folder, out, "--resume")) == 1
    assert "after 2 of 2 trials" in capsys.readouterr().out


def test_a_glob_pattern_through_the_python_api(recorded, uninterrupted, tmp_path):
    """A glob pattern names the trials; `db.fit_trials` is the command's loop, with the
    optional outputs by name. The pattern names b alone, so the registration fits b's
    frames (all 4 of the default 8) beside the static trial, not a's too: b's row is the
    command's but for its marker RMS."""
    static, trials = recorded
    out = tmp_path / "fits"
    lines = []
    result = db.fit_trials(
        db.load_body(),
        static,
        str(trials / "b*.trc"),
        "opensim-gait",
        out,
        prior=False,
        outputs=("trc", "png"),
        log=lines.append,
    )
    assert isinstance(result, db.TrialsSummary) and result.ok
    assert (result.total, result.fitted, result.resumed) == (1, ("b.trc",), ())
    assert {p.name for p in out.iterdir()} == {
        "b.npz",
        "b.model.trc",
        "b.png",
        "body.json",
        "body.spine.json",
        "trials.csv",
    }
    assert read_trc(out / "b.model.trc").n_frames == 4 and (out / "b.png").stat().st_size > 0
    row = next(csv.reader(data_lines(out / "trials.csv")[1:]))
    command_row = next(csv.reader(data_lines(uninterrupted / "trials.csv")[2:]))
    assert row[:6] == command_row[:6] and abs(float(row[6]) - float(command_row[6])) < 2e-3
    assert any(line.startswith("b.trc: 4 frames") for line in lines)
    assert "  registered on 4 frames of 1 motion trial(s) as well" in "\n".join(lines)
    # OpenSim's best practices, the static fit's and each trial's, as for one trial.
    assert any("scaling, " in line and "bony landmarks, RMS" in line for line in lines)
    assert any(line.startswith("  motion, frames with RMS < 2 cm") for line in lines)
    again = db.fit_trials(
        db.load_body(),
        static,
        str(trials / "b*.trc"),
        out_dir=out,
        prior=False,
        resume=True,
        log=lines.append,
    )
    assert (again.fitted, again.resumed) == ((), ("b.trc",))


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--png", "x.png"], "--png x.png: with several trials give --png alone"),
        (["--resume", "--out", "fits.npz"], "--out fits.npz: is a file"),
    ],
)
def test_folder_options_exit_2(recorded, tmp_path, capsys, monkeypatch, extra, message):
    static, trials = recorded
    (tmp_path / "fits.npz").write_text("")
    monkeypatch.chdir(tmp_path)
    assert main(["mocap", str(static), str(trials), *extra]) == 2
    assert message in capsys.readouterr().err


def test_one_trial_options_exit_2(recorded, tmp_path, capsys):
    static, trials = recorded
    one = ["mocap", str(static), str(trials / "a.trc"), "--out", str(tmp_path / "f.npz")]
    assert main(one + ["--mot"]) == 2
    assert "--mot: give a .mot file name" in capsys.readouterr().err
    assert main(one + ["--resume"]) == 2
    assert "--resume: for a folder or a glob pattern of trials" in capsys.readouterr().err
    assert main(["mocap", str(static), str(tmp_path / "none*.trc")]) == 2
    assert "no file matches this pattern" in capsys.readouterr().err
