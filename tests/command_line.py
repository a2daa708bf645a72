"""Shared helpers of the command-line tests."""

from diffbody.cli import main

# The left arm from one start in chunks of 2: the compiled solve of tests/ik/test_batch.py,
# reused by every `batch` test.
ARM_BATCH = ["--segments", "left_upper_arm", "left_forearm", "left_hand", "--starts", "1"]
ARM_BATCH += ["--chunk-size", "2"]


def arm_batch(targets, results) -> list[str]:
    """argv of `diffbody batch` solving the left palm's targets with the arm alone."""
    return ["batch", str(targets), "--effector", "left_hand.palm", "--out", str(results)]


def fails(argv, capsys) -> str:
    """Run the command line; check that it exits 2 without a traceback; its stderr."""
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's usage errors
        code = e.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    return err


def data_lines(path) -> list[str]:
    """A streamed results file's lines after its `#` header (column names first)."""
    return [line for line in path.read_text().splitlines(True) if not line.startswith("#")]


def without_timestamp(path) -> str:
    """The file's text without its `# begun:` line, the one line two runs may differ in."""
    lines = path.read_text().splitlines(True)
    assert sum(line.startswith("# begun: ") for line in lines) == 1
    return "".join(line for line in lines if not line.startswith("# begun: "))
