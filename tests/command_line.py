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
