"""`diffbody batch` on long runs: results written a chunk at a time, interrupts that keep
every finished chunk, and `--resume` that gives the rows of an uninterrupted run.

The signals need a process of their own: `python -m diffbody batch` with the tests'
environment (its compilation cache and XLA flags) and float64, so that its rows are those of
the in-process runs. Those (diffbody.cli._main.main) are the cheaper rest.
"""

import csv
import gc
import os
import queue
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from command_line import ARM_BATCH, arm_batch, data_lines, without_timestamp

import diffbody as db
from diffbody.cli._main import main
from diffbody.files import structure_hash

ROWS = 60  # 30 chunks of 2: the run is still going when its second chunk is written


def write_targets(path, n=ROWS, seed=0):
    """n targets around the left palm's reach, some beyond it, with a header."""
    rng = np.random.default_rng(seed)
    points = np.array([0.3, 0.2, 1.0]) + rng.uniform(-0.12, 0.12, (n, 3))
    path.write_text("x,y,z\n" + "".join(",".join(f"{v:.4f}" for v in p) + "\n" for p in points))
    return path


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The targets and the results file and postures of a run that was never stopped."""
    folder = tmp_path_factory.mktemp("uninterrupted")
    targets = write_targets(folder / "targets.csv")
    results = folder / "results.csv"
    assert main(arm_batch(targets, results) + ARM_BATCH) == 0
    return targets, results


def start(targets, results, *extra, **environ):
    """`diffbody batch` in a process of its own, float64 as the tests run (and `environ`)."""
    env = dict(os.environ, JAX_ENABLE_X64="1", **environ)
    argv = [sys.executable, "-m", "diffbody"] + arm_batch(targets, results) + ARM_BATCH
    return subprocess.Popen(
        argv + list(extra), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def stop_after(process, results, rows, signum):
    """Send `signum` once `results` holds `rows` rows; the process's exit status, stdout and
    stderr. The run must still be going then (else the test proves nothing)."""
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and process.poll() is None:
        if results.exists() and len(data_lines(results)) - 1 >= rows:
            break
        time.sleep(0.01)
    assert process.poll() is None, process.communicate()
    process.send_signal(signum)
    out, err = process.communicate(timeout=120)
    return process.returncode, out, err


def stop_while_compiling(process, signum):
    """Send `signum` once XLA has spent a second on one program (the process logs each
    program's lowering, then its compile: JAX_LOG_COMPILES); the exit status and stderr."""
    seen, lines = [], queue.Queue()

    def read():
        for line in process.stderr:
            seen.append(line)
            lines.put(line)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    with process:  # closes the pipes
        deadline, lowered = time.monotonic() + 240, False
        while time.monotonic() < deadline and process.poll() is None:
            try:
                lowered = "Finished jaxpr to MLIR module conversion" in lines.get(timeout=1)
            except queue.Empty:
                if lowered:
                    break
        assert process.poll() is None and lowered, "".join(seen)
        process.send_signal(signum)
        process.wait(timeout=120)
        reader.join(timeout=10)
    return process.returncode, "".join(seen)


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_run_stopped_while_it_compiles_exits_cleanly(
    uninterrupted, tmp_path, capsys, signum, code
):
    """A signal while XLA compiles the solver (an empty compilation cache), before any chunk
    is written: the compile goes on in XLA's threads, and the process still exits with the
    signal's status at once, not of a segmentation fault at its teardown (139), with the
    file begun and nothing half-written; --resume gives the uninterrupted run's file."""
    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    cold = dict(JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"), JAX_LOG_COMPILES="1")
    status, err = stop_while_compiling(start(targets, results, **cold), signum)
    assert status == code, err
    for crash in ("Traceback", "KeyboardInterrupt", "Fatal Python error", "Exception ignored"):
        assert crash not in err, err
    message = f"interrupted after 0 of {ROWS} rows; {results} holds them; rerun with --resume"
    assert message in err
    assert sorted(os.listdir(tmp_path)) == ["cache", "results.csv"]
    assert len(data_lines(results)) == 1  # the column names, no row

    assert main(arm_batch(targets, results) + ARM_BATCH + ["--resume"]) == 0
    assert f"resuming {results} after 0 of {ROWS} rows" in capsys.readouterr().out
    assert without_timestamp(results) == without_timestamp(reference)


def test_a_signal_taken_where_python_ignores_exceptions_still_stops(capsys):
    """A signal handled in a gc callback (JAX's runs at every collection, often during a
    compile) or a __del__, where Python prints the exception and goes on, still stops the
    run: it is sent again once that code has returned, and nothing is printed."""
    from diffbody.runs._streaming import Interrupted, Interrupts

    sent = []

    def callback(phase, info):
        if phase == "start" and not sent:
            sent.append(phase)
            signal.raise_signal(signal.SIGINT)  # handled here, in the callback

    gc.callbacks.append(callback)
    try:
        with pytest.raises(Interrupted) as stopped, Interrupts():
            gc.collect()
            time.sleep(10)  # the signal comes again, and ends the sleep
    finally:
        gc.callbacks.remove(callback)
    assert sent and stopped.value.code == 130
    assert "Exception ignored" not in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupted_run_keeps_its_chunks_and_resumes(
    uninterrupted, tmp_path, capsys, signum, code
):
    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    status, _, err = stop_after(start(targets, results), results, 4, signum)
    assert status == code, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    done = len(data_lines(results)) - 1
    assert 4 <= done < ROWS and done % 2 == 0
    message = f"interrupted after {done} of {ROWS} rows; {results} holds them; rerun with --resume"
    assert message in err
    parts = sorted(os.listdir(tmp_path / "results.poses"))
    assert parts == [f"part-{i:05d}.npz" for i in range(done // 2)]
    assert not (tmp_path / "results.poses.npz").exists()
    assert db.load_pose(tmp_path / "results.poses" / "part-00001.npz").n_frames == 2

    assert main(arm_batch(targets, results) + ARM_BATCH + ["--resume"]) == 0
    out = capsys.readouterr().out
    assert f"resuming {results} after {done} of {ROWS} rows" in out
    assert without_timestamp(results) == without_timestamp(reference)
    assert not (tmp_path / "results.poses").exists()
    merged = db.load_pose(tmp_path / "results.poses.npz")
    expected = db.load_pose(reference.with_name("results.poses.npz"))
    assert merged.n_frames == ROWS and merged.status == expected.status
    np.testing.assert_array_equal(merged.pose.angles, expected.pose.angles)
    np.testing.assert_array_equal(merged.extra["steps"], expected.extra["steps"])


@pytest.mark.slow
def test_a_killed_run_leaves_whole_rows_and_resumes(uninterrupted, tmp_path, capsys):
    """SIGKILL gives the run no say: what it leaves is whole rows; a partial last line and
    rows beyond the last whole chunk (as a crash in the middle of a write could leave) are
    cut off by --resume, a half-written part removed, and the run completed."""
    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    status, _, _ = stop_after(start(targets, results), results, 4, signal.SIGKILL)
    assert status == -signal.SIGKILL
    lines = data_lines(results)
    assert lines[0].startswith("row,") and all(line.endswith("\n") for line in lines)
    rows = list(csv.DictReader(lines))
    assert len(rows) >= 4 and [r["row"] for r in rows] == [str(i) for i in range(len(rows))]
    for r in rows:
        assert None not in r and None not in r.values()  # every column, none more
        assert float(r["left_hand.palm.residual"]) >= 0 and r["status"]

    whole = len(rows) - len(rows) % 2
    with results.open("a") as f:  # one row of the next chunk, and half a row after it
        f.write(f"{whole},0.5,0,1,unreachable,30\n{whole + 1},0.0")
    (tmp_path / "results.poses" / f"part-{whole // 2:05d}.partial.npz").write_bytes(b"PK")
    assert main(arm_batch(targets, results) + ARM_BATCH + ["--resume"]) == 0
    assert f"after {whole} of {ROWS} rows" in capsys.readouterr().out
    assert without_timestamp(results) == without_timestamp(reference)
    assert not (tmp_path / "results.poses").exists()


def test_a_keyboard_interrupt_inside_a_solve_is_a_clean_stop(
    uninterrupted, tmp_path, capsys, monkeypatch
):
    """A KeyboardInterrupt from inside a chunk's solve (not through the command's handler)
    drops that chunk, keeps the finished ones, and says so; the handlers are put back."""
    import diffbody.ik._reach_run as reach_run

    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    solve, calls, stop_at = reach_run.solve_reach_batch, [], [3]

    def solve_then_stop(*args, **kwargs):
        calls.append(1)
        if len(calls) in stop_at:
            raise KeyboardInterrupt
        return solve(*args, **kwargs)

    monkeypatch.setattr(reach_run, "solve_reach_batch", solve_then_stop)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert main(arm_batch(targets, results) + ARM_BATCH) == 130
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    err = capsys.readouterr().err
    assert f"interrupted after 4 of {ROWS} rows; {results} holds them" in err
    assert len(data_lines(results)) == 1 + 4
    assert (tmp_path / "results.poses" / "part-00001.npz").exists()
    stop_at.clear()
    assert main(arm_batch(targets, results) + ARM_BATCH) == 0  # no --resume: starts over
    assert without_timestamp(results) == without_timestamp(reference)
    assert not (tmp_path / "results.poses").exists()
    assert len(calls) == 3 + ROWS // 2
    # --resume of a complete run: nothing left to solve, the file as it was.
    text = results.read_text()
    assert main(arm_batch(targets, results) + ARM_BATCH + ["--resume"]) == 0
    assert f"after {ROWS} of {ROWS} rows" in capsys.readouterr().out
    assert results.read_text() == text and len(calls) == 3 + ROWS // 2
    assert db.load_pose(tmp_path / "results.poses.npz").n_frames == ROWS


def test_the_header_records_the_run(uninterrupted):
    import hashlib

    targets, reference = uninterrupted
    lines = reference.read_text().splitlines()
    header = dict(line[2:].split(": ", 1) for line in lines if line.startswith("# "))
    assert header["format"] == "diffbody.batch/1" and header["rows"] == str(ROWS)
    assert header["input-sha256"] == hashlib.sha256(targets.read_bytes()).hexdigest()
    assert header["body"] == "male50"
    assert header["body-structure"] == structure_hash(db.load_body())
    assert header["effectors"] == "left_hand.palm" and header["chunk-size"] == "2"
    assert header["segments"] == "left_upper_arm left_forearm left_hand"
    assert header["starts"] == "1" and header["spine"] == "on" and header["float"] == "float64"
    assert lines[len(header)].startswith("row,left_hand.palm.residual,")


@pytest.mark.parametrize(
    "change, message",
    [
        ("input", "the input file changed (sha256 "),
        (["--variant", "female50"], "the body changed (male50: structure"),
        (["--starts", "2"], "--starts changed from 1 to 2"),
        (["--chunk-size", "4"], "--chunk-size changed from 2 to 4"),
        (["--segments", "left_forearm", "left_hand"], "--segments changed from left_upper_arm"),
        (["--no-spine"], "the spine (--no-spine) changed from on to off"),
    ],
)
def test_resume_refuses_a_different_run(uninterrupted, tmp_path, capsys, change, message):
    """--resume of a file begun with other targets, body or settings is refused before any
    solve, naming what changed, and the file is left as it was."""
    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    results.write_text(reference.read_text())
    argv = arm_batch(targets, results) + ARM_BATCH
    if change == "input":
        changed = write_targets(tmp_path / "targets.csv", seed=1)
        argv = arm_batch(changed, results) + ARM_BATCH
    else:
        argv += change  # argparse: the last --starts / --chunk-size / --segments wins
    assert main(argv + ["--resume"]) == 2
    err = capsys.readouterr().err
    assert f"diffbody: error: --resume {results}: {message}" in err, err
    assert "rerun as it was begun, or without --resume to start over" in err
    assert err.count("changed") == 1  # only what changed is named
    assert results.read_text() == reference.read_text()


def test_merged_postures_name_one_spine_target_for_every_row(male50, tmp_path):
    """A chunk whose rows the limbs alone reached has no spine target; merged with a chunk
    where the trunk moved, its rows get the start's spine, as one solve of all rows gives."""
    from types import SimpleNamespace

    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from diffbody.runs._batch_postures import merge_postures, write_part

    rest = male50.rest_pose()
    assert rest.spine_target is None
    two = jax.tree.map(lambda a: jnp.stack([a, a]), rest)
    bent = jnp.asarray([[0.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    with_spine = eqx.tree_at(lambda p: p.spine_target, two, bent, is_leaf=lambda x: x is None)
    xyz = np.full((2, 1, 3), 0.3)
    for index, pose in enumerate([two, with_spine]):
        result = SimpleNamespace(
            pose=pose,
            status=np.zeros(2, int),
            residuals=np.zeros((2, 1)),
            reached=np.ones((2, 1), bool),
            valid=np.ones((2, 1), bool),
            steps=np.arange(2),
        )
        write_part(str(tmp_path / "r.poses"), index, male50, result, xyz, ["left_hand.palm"])
    merge_postures(str(tmp_path / "r.poses"), 2, str(tmp_path / "r.poses.npz"), male50, ["x"])
    merged = db.load_pose(tmp_path / "r.poses.npz", male50)
    start = np.asarray(db.spine_angles(male50, male50.spine, rest).sum(0))
    np.testing.assert_allclose(merged.pose.spine_target[:2], [start, start], atol=1e-12)
    np.testing.assert_allclose(merged.pose.spine_target[2:], bent, atol=1e-12)
    assert merged.n_frames == 4 and list(merged.extra["steps"]) == [0, 1, 0, 1]


ARM = dict(segments=["left_upper_arm", "left_forearm", "left_hand"], starts=1, chunk_size=2)


def test_python_writes_the_same_file_and_resumes(uninterrupted, tmp_path, monkeypatch):
    """`run_reach_batch` writes the command's file; a KeyboardInterrupt inside
    a chunk's solve keeps the finished chunks and says how far (`Interrupted`, a
    KeyboardInterrupt); `resume=True` completes it; a changed setting is refused by its
    keyword."""
    import diffbody.ik._reach_run as reach_run
    from diffbody.runs._streaming import Interrupted

    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    body = db.load_body()
    solve, calls = reach_run.solve_reach_batch, []

    def solve_then_stop(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return solve(*args, **kwargs)

    monkeypatch.setattr(reach_run, "solve_reach_batch", solve_then_stop)
    with pytest.raises(KeyboardInterrupt) as stopped:
        db.run_reach_batch(body, ["left_hand.palm"], targets, results, progress=False, **ARM)
    assert isinstance(stopped.value, Interrupted) and stopped.value.done == 4
    assert f"interrupted after 4 of {ROWS} rows; {results} holds them" in str(stopped.value)
    with pytest.raises(ValueError, match="starts= changed from 1 to 2; rerun as it was begun"):
        db.run_reach_batch(
            body, ["left_hand.palm"], targets, results, resume=True, **(ARM | {"starts": 2})
        )
    run = db.run_reach_batch(
        body, ["left_hand.palm"], targets, results, resume=True, progress=False, **ARM
    )
    assert (run.rows, run.solved, run.out) == (ROWS, ROWS - 4, str(results))
    assert without_timestamp(results) == without_timestamp(reference)
    assert run.load().n_frames == ROWS and run.reached == int(np.sum(run.load().extra["reached"]))


def test_parquet_targets_give_the_csv_rows(uninterrupted, tmp_path):
    """A Parquet file of the same targets: the same result rows, read a record batch at a
    time; a Parquet file with a text column is refused naming it."""
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    from diffbody.files._targets_file import read_targets

    targets, reference = uninterrupted
    xyz = read_targets(targets, 1)[:, 0]
    table = pa.table({name: xyz[:, i] for i, name in enumerate("xyz")})
    pq.write_table(table, tmp_path / "targets.parquet", row_group_size=7)
    results = tmp_path / "results.csv"
    assert main(arm_batch(tmp_path / "targets.parquet", results) + ARM_BATCH) == 0
    assert data_lines(results) == data_lines(reference)
    bad = pa.table({"x": ["a"], "y": [0.2], "z": [1.0]})
    pq.write_table(bad, tmp_path / "bad.parquet")
    with pytest.raises(ValueError, match=r"bad.parquet: column 1 \(x\): string, not numbers"):
        read_targets(tmp_path / "bad.parquet", 1)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_processes_merge_to_the_one_process_file(uninterrupted, tmp_path):
    """Two processes on this machine through jax.distributed (CPU, gloo): each solves half
    the chunks into its own part, process 0 merges them; the result is the one-process
    file row for row, and the postures the same."""
    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    address = f"localhost:{free_port()}"
    processes = [
        start(targets, results, "--coordinator", address, "--num-processes", "2",
              "--process-id", str(i))
        for i in range(2)
    ]  # fmt: skip
    for i, p in enumerate(processes):
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        assert f"process {i} of 2" in out
    assert without_timestamp(results) == without_timestamp(reference)
    assert sorted(os.listdir(tmp_path)) == ["results.csv", "results.poses.npz"]
    merged = db.load_pose(tmp_path / "results.poses.npz")
    expected = db.load_pose(reference.with_name("results.poses.npz"))
    np.testing.assert_array_equal(merged.pose.angles, expected.pose.angles)


def test_ctrl_c_while_the_targets_are_checked_writes_nothing(tmp_path, capsys, monkeypatch):
    """A Ctrl-C before the results file is begun (here while a long targets file is still
    being checked) exits 130 without a traceback and writes nothing."""
    import diffbody.runs._batch_run as batch_run

    def stopped(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(batch_run, "scan_targets", stopped)
    targets, results = write_targets(tmp_path / "targets.csv"), tmp_path / "results.csv"
    assert main(arm_batch(targets, results) + ARM_BATCH) == 130
    assert f"interrupted before {results} was begun; nothing written" in capsys.readouterr().err
    assert not results.exists()


def test_sigterm_while_the_targets_are_checked_writes_nothing(tmp_path, capsys, monkeypatch):
    """SIGTERM before the results file is begun is told as Ctrl-C is: exit 143, nothing
    written."""
    import diffbody.runs._batch_run as batch_run

    def stopped(*args):
        signal.raise_signal(signal.SIGTERM)
        time.sleep(10)  # the command's handler ends it

    def unhandled(signum, frame):  # rather than ending pytest
        pytest.fail("the command left SIGTERM to the default handler")

    monkeypatch.setattr(batch_run, "scan_targets", stopped)
    targets, results = write_targets(tmp_path / "targets.csv"), tmp_path / "results.csv"
    before = signal.signal(signal.SIGTERM, unhandled)
    try:
        assert main(arm_batch(targets, results) + ARM_BATCH) == 143
    finally:
        signal.signal(signal.SIGTERM, before)
    assert f"interrupted before {results} was begun; nothing written" in capsys.readouterr().err
    assert not results.exists()


def test_ctrl_c_while_the_postures_are_merged_says_so_and_resumes(
    uninterrupted, tmp_path, capsys, monkeypatch
):
    """A Ctrl-C once every row is written, while the chunks' postures are merged: told as
    the rows it holds (not as nothing written), exit 130; --resume merges them."""
    import diffbody.runs._batch_run as batch_run

    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    merge, calls = batch_run.merge_postures, []

    def stopped(*args):
        calls.append(1)
        if len(calls) == 1:
            raise KeyboardInterrupt
        merge(*args)

    monkeypatch.setattr(batch_run, "merge_postures", stopped)
    assert main(arm_batch(targets, results) + ARM_BATCH) == 130
    message = f"interrupted after {ROWS} of {ROWS} rows; {results} holds them; rerun with --resume"
    assert message in capsys.readouterr().err
    assert main(arm_batch(targets, results) + ARM_BATCH + ["--resume"]) == 0
    assert without_timestamp(results) == without_timestamp(reference)
    assert sorted(os.listdir(tmp_path)) == ["results.csv", "results.poses.npz"]


@pytest.mark.slow
def test_a_stopped_process_leaves_every_share_to_resume(uninterrupted, tmp_path):
    """Process 1 stopped (SIGINT) before its share is done: process 0 finishes its share,
    nothing is merged, both exit 130 saying so; both rerun with --resume give the one
    process's file."""
    targets, reference = uninterrupted
    results = tmp_path / "results.csv"
    part = tmp_path / "results.process-1-of-2.csv"

    def both(*extra):
        address = f"localhost:{free_port()}"
        many = ["--coordinator", address, "--num-processes", "2", *extra]
        return [start(targets, results, *many, "--process-id", str(i)) for i in range(2)]

    first, second = both()
    deadline = time.monotonic() + 240
    while not part.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    second.send_signal(signal.SIGINT)  # while it compiles or solves its first chunk
    (_, err0), (_, err1) = first.communicate(timeout=600), second.communicate(timeout=600)
    assert (first.returncode, second.returncode) == (130, 130), (err0, err1)
    assert "another process stopped before its share was done, so nothing was merged" in err0
    assert "interrupted after " in err1 and "Traceback" not in err0 + err1
    assert not results.exists() and part.exists()
    for p in both("--resume"):
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
    assert without_timestamp(results) == without_timestamp(reference)
    assert sorted(os.listdir(tmp_path)) == ["results.csv", "results.poses.npz"]
